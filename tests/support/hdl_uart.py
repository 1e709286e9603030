"""UARTs nobody here wrote, as the references for the emulator's line model: LiteX's
``RS232PHYRX`` / ``RS232PHYTX`` (PyPI ``litex``, written in ``migen``), converted to Verilog
by migen, for the edge-triggered receiver; OpenTitan's ``uart_rx`` (lowRISC, Apache-2.0,
shipped on PyPI as ``pythondata-misc-opentitan``: read from the installed package, never
copied here), for the level-triggered one. Both simulated cycle by cycle with Icarus
Verilog (Debian ``iverilog``).

OpenTitan's receiver runs behind a two-flip-flop synchroniser (as its ``uart_core`` puts
it) on a 16× tick from a free-running divider started at reset (16 ticks spread evenly over
each ``cycles_per_bit`` cycles): :class:`fpgaemu.uart.LevelReceiver`'s clock.

The receiver is fed a line waveform given as one level per bit slot (1 = idle/high), one
level per clock for ``cycles_per_bit`` clocks; it reports every byte (``source.valid``) and
every frame it dropped for a low stop bit (LiteX has no framing-error output: the FSM
leaving RUN without ``valid`` is where it drops one). Cycle 0 is the first cycle of slot 0,
and the line is idle before it. The transmitter is offered bytes back to back and reports
where its start bits begin.

Tuning word as ``RS232PHY`` computes it: ``int(baud / clk * 2**32)``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["HdlUart", "available", "why_unavailable"]

#: reset cycles, then idle cycles, before slot 0
PREROLL = 20
Event = tuple[str, int, int]  #: ("byte" | "framing_error", value, cycle)

_TB_RX = r"""
`timescale 1ns/1ps
module tb;
  reg clk = 0, rst = 1, rx = 1, running = 0;
  wire ev_byte, ev_ferr; wire [7:0] ev_data;
  ref_rx dut(.clk(clk), .rst(rst), .rx(rx), .ev_byte(ev_byte), .ev_ferr(ev_ferr),
             .ev_data(ev_data));
  always #5 clk = ~clk;
  integer fd, r, nscen, slotlen, s, nslots, i, c, ch;
  reg [1023:0] fname;
  always @(negedge clk) if (running) begin
    if (ev_byte) $display("B %0d %0d", ev_data, c);
    if (ev_ferr) $display("F %0d %0d", ev_data, c);
    c = c + 1;
  end
  initial begin
    if (!$value$plusargs("in=%s", fname)) begin $display("no +in="); $finish; end
    fd = $fopen(fname, "r");
    r = $fscanf(fd, "%d\n", nscen);
    for (s = 0; s < nscen; s = s + 1) begin
      r = $fscanf(fd, "%d %d\n", nslots, slotlen);
      @(posedge clk); #1 rst = 1; rx = 1;
      repeat (3) @(posedge clk);
      #1 rst = 0;
      repeat (`PREROLL - 1) @(posedge clk);
      for (i = 0; i < nslots; i = i + 1) begin
        ch = $fgetc(fd);
        @(posedge clk); #1 rx = (ch == "1");
        if (i == 0) begin running = 1; c = 0; end
        repeat (slotlen - 1) @(posedge clk);
      end
      @(posedge clk); #1 running = 0;
      ch = $fgetc(fd);
      $display("E");
    end
    $finish;
  end
endmodule
"""

_TB_TX = r"""
`timescale 1ns/1ps
module tb;
  reg clk = 0, rst = 1, sink_valid = 0;
  reg [7:0] sink_data = 0;
  wire tx, sink_ready;
  ref_tx dut(.clk(clk), .rst(rst), .tx(tx), .sink_valid(sink_valid), .sink_ready(sink_ready),
             .sink_data(sink_data));
  always #5 clk = ~clk;
  integer fd, r, nbytes, ncycles, i, c, idx, hs, prev;
  reg [7:0] mem [0:65535];
  reg [1023:0] fname;
  initial begin
    if (!$value$plusargs("in=%s", fname)) begin $display("no +in="); $finish; end
    fd = $fopen(fname, "r");
    r = $fscanf(fd, "%d %d\n", nbytes, ncycles);
    for (i = 0; i < nbytes; i = i + 1) r = $fscanf(fd, "%d\n", mem[i]);
    @(posedge clk); #1 rst = 1;
    repeat (3) @(posedge clk);
    #1 rst = 0;
    repeat (`PREROLL - 1) @(posedge clk);
    idx = 0; hs = 0; prev = 1;
    for (c = 0; c < ncycles; c = c + 1) begin
      @(posedge clk); #1;
      if (hs) idx = idx + 1;
      sink_valid = (idx < nbytes);
      sink_data = (idx < nbytes) ? mem[idx] : 8'd0;
      #3;
      hs = sink_valid & sink_ready;
      if (tx != prev) $display("T %0d %0d", tx, c);
      prev = tx;
    end
    $display("E");
    $finish;
  end
endmodule
"""


def why_unavailable() -> str | None:
    """Why the reference cannot run here (``None`` when it can)."""
    if shutil.which("iverilog") is None or shutil.which("vvp") is None:
        return "Icarus Verilog (iverilog, vvp) is not installed (the Makefile installs it)"
    try:
        import litex.soc.cores.uart  # noqa: F401
        import migen  # noqa: F401
        import pythondata_misc_opentitan  # noqa: F401
    except ImportError as exc:
        return (f"litex/migen/pythondata-misc-opentitan are not installed ({exc}); "
                "pip install -e '.[dev]'")
    return None


def opentitan_uart_rx() -> Path:
    """OpenTitan's ``uart_rx.sv`` in the installed ``pythondata-misc-opentitan``."""
    import pythondata_misc_opentitan

    return Path(pythondata_misc_opentitan.data_location) / "hw/ip/uart/rtl/uart_rx.sv"


#: OpenTitan's receiver as ``ref_rx``: a two-flip-flop synchroniser on ``rx`` and the 16×
#: tick from a divider that adds 16 per cycle and ticks on passing ``CPB``.
_LEVEL_SHIM = r"""
module ref_rx(input clk, input rst, input rx, output ev_byte, output ev_ferr,
              output [7:0] ev_data);
  reg s1, s2, tick;
  reg [15:0] acc;
  wire valid, idle, ferr, perr, baud;
  always @(posedge clk) begin
    if (rst) begin s1 <= 1; s2 <= 1; acc <= 0; tick <= 0; end
    else begin
      s1 <= rx; s2 <= s1;
      if (acc + 16 >= `CPB) begin acc <= acc + 16 - `CPB; tick <= 1; end
      else begin acc <= acc + 16; tick <= 0; end
    end
  end
  uart_rx core(.clk_i(clk), .rst_ni(~rst), .rx_enable(1'b1), .tick_baud_x16(tick),
               .parity_enable(1'b0), .parity_odd(1'b0), .tick_baud(baud),
               .rx_valid(valid), .rx_data(ev_data), .idle(idle), .frame_err(ferr),
               .rx_parity_err(perr), .rx(s2));
  assign ev_byte = valid & ~ferr;
  assign ev_ferr = valid & ferr;
endmodule
"""


def available() -> bool:
    return why_unavailable() is None


def _tuning_word(cycles_per_bit: int) -> int:
    clk = 100e6
    return int((clk / cycles_per_bit / clk) * 2**32)


def _design(kind: str, cycles_per_bit: int) -> str:
    from litex.soc.cores.uart import RS232PHYRX, RS232PHYTX, UARTPads
    from migen import Module, Signal
    from migen.fhdl import verilog

    word = _tuning_word(cycles_per_bit)
    module: Any = Module()
    pads = UARTPads()
    if kind == "rx":
        phy = RS232PHYRX(pads, word)
        module.submodules.phy = phy
        ev_byte, ev_ferr, ev_data = Signal(name="ev_byte"), Signal(name="ev_ferr"), \
            Signal(8, name="ev_data")
        module.comb += [
            phy.source.ready.eq(1),
            ev_byte.eq(phy.source.valid),
            ev_ferr.eq(phy.fsm.before_leaving("RUN") & ~phy.source.valid),
            ev_data.eq(phy.source.data),
        ]
        text = str(verilog.convert(module, ios={pads.rx, ev_byte, ev_ferr, ev_data},
                                   name="litex_rx"))
        shim = ("module ref_rx(input clk, input rst, input rx, output ev_byte, output ev_ferr,"
                " output [7:0] ev_data);\n  litex_rx core(.sys_clk(clk), .sys_rst(rst),"
                " .rx(rx), .ev_byte(ev_byte), .ev_ferr(ev_ferr), .ev_data(ev_data));\n"
                "endmodule\n")
    else:
        phy = RS232PHYTX(pads, word)
        module.submodules.phy = phy
        valid, ready, data = Signal(name="sink_valid"), Signal(name="sink_ready"), \
            Signal(8, name="sink_data")
        module.comb += [phy.sink.valid.eq(valid), phy.sink.data.eq(data),
                        ready.eq(phy.sink.ready)]
        text = str(verilog.convert(module, ios={pads.tx, valid, ready, data}, name="litex_tx"))
        shim = ("module ref_tx(input clk, input rst, output tx, input sink_valid,"
                " output sink_ready, input [7:0] sink_data);\n  litex_tx core(.sys_clk(clk),"
                " .sys_rst(rst), .tx(tx), .sink_valid(sink_valid), .sink_ready(sink_ready),"
                " .sink_data(sink_data));\nendmodule\n")
    return text + "\n" + shim


@dataclass
class HdlUart:
    """LiteX's UART PHY at ``cycles_per_bit`` (``level``: OpenTitan's receiver instead),
    built into ``workdir`` on first use."""

    workdir: Path
    cycles_per_bit: int = 100
    level: bool = False

    def _build(self, kind: str) -> Path:
        if self.level:
            out = self.workdir / f"opentitan_{kind}_{self.cycles_per_bit}"
            vvp = out / "sim.vvp"
            if not vvp.exists():
                out.mkdir(parents=True, exist_ok=True)
                (out / "shim.v").write_text(_LEVEL_SHIM)
                (out / "tb.v").write_text(_TB_RX)
                subprocess.run(["iverilog", "-g2012", f"-DPREROLL={PREROLL}",
                                f"-DCPB={self.cycles_per_bit}", "-s", "tb", "-o", str(vvp),
                                str(out / "tb.v"), str(out / "shim.v"),
                                str(opentitan_uart_rx())], check=True, capture_output=True)
            return vvp
        out = self.workdir / f"litex_{kind}_{self.cycles_per_bit}"
        vvp = out / "sim.vvp"
        if not vvp.exists():
            out.mkdir(parents=True, exist_ok=True)
            (out / "design.v").write_text(_design(kind, self.cycles_per_bit))
            (out / "tb.v").write_text(_TB_RX if kind == "rx" else _TB_TX)
            subprocess.run(["iverilog", "-g2005", f"-DPREROLL={PREROLL}", "-s", "tb", "-o",
                            str(vvp), str(out / "tb.v"), str(out / "design.v")],
                           check=True, capture_output=True)
        return vvp

    def _run(self, kind: str, text: str) -> list[str]:
        vvp = self._build(kind)
        stimulus = vvp.parent / f"in-{os.getpid()}.txt"
        stimulus.write_text(text)
        try:
            done = subprocess.run(["vvp", "-n", str(vvp), f"+in={stimulus}"],
                                  capture_output=True, text=True, check=True, timeout=300)
        finally:
            stimulus.unlink(missing_ok=True)
        return done.stdout.splitlines()

    def receive(self, waveforms: list[list[int]]) -> list[list[Event]]:
        """Every waveform through the receiver, in one simulator run (reset between)."""
        lines = [str(len(waveforms))]
        for slots in waveforms:
            lines += [f"{len(slots)} {self.cycles_per_bit}", "".join(map(str, slots))]
        results: list[list[Event]] = []
        current: list[Event] = []
        for line in self._run("rx", "\n".join(lines) + "\n"):
            parts = line.split()
            if parts and parts[0] == "E":
                results.append(current)
                current = []
            elif parts and parts[0] in ("B", "F"):
                current.append(("byte" if parts[0] == "B" else "framing_error",
                                int(parts[1]), int(parts[2])))
        if len(results) != len(waveforms):
            raise RuntimeError("the simulation's output was cut short")
        return results

    def transmit_starts(self, data: bytes) -> list[int]:
        """Cycles at which each start bit begins when ``data`` is offered back to back."""
        cycles = len(data) * 11 * self.cycles_per_bit + 4 * self.cycles_per_bit
        text = f"{len(data)} {cycles}\n" + "".join(f"{b}\n" for b in data)
        level, starts = 1, []
        for line in self._run("tx", text):
            parts = line.split()
            if parts and parts[0] == "T":
                new, cycle = int(parts[1]), int(parts[2])
                if new == 0 and level == 1:
                    starts.append(cycle)
                level = new
        # A falling edge inside a byte (a 1 → 0 data transition) is not a start: keep the
        # edges that are a whole byte apart.
        frames: list[int] = []
        for cycle in starts:
            if not frames or cycle - frames[-1] >= 10 * self.cycles_per_bit:
                frames.append(cycle)
        return frames
