"""The board: the seed's figures 3.1–3.2 wired on one timeline.

    host ─RX pin─► uartread ─► uartcommand ─► blk_mem_gen (RX) ─┐
                                  │ global_enable, interrupt     ├─ AxiBus ◄─ MicroBlaze
    host ◄TX pin── uartwrite ◄─ uartsend ◄─ blk_mem_gen (TX) ◄───┘           (firmware)
                                  │ global_enable                              │
                       timer ─────┼──────────── interrupt ─────────────────────┤
    channel A, B:  pwm ◄──────────┴─── duty ───────────────────────────────────┤
                   encoder, current sensor ── position, speed, current ────────┘

The host-facing API is what a serial port gives: ``host_write`` puts bytes on the RX pin at
a cycle, ``read_host_bytes`` returns the TX bytes whose stop bit has ended. The software
(:mod:`fpgaemu.firmware`) and the physical world (:mod:`fpgaemu.motor`) attach with
:meth:`Board.add_peripheral`; :func:`fpgaemu.build.build_board` puts a whole board together.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from fpgaemu.axi import AxiBus
from fpgaemu.bram import BRAM_BYTES, BlockRam
from fpgaemu.encoder import QuadratureEncoder
from fpgaemu.pwm import Pwm
from fpgaemu.timeline import EventHandle, Timeline, seconds_to_cycles
from fpgaemu.timer import Timer
from fpgaemu.uart import DEFAULT_BAUD, LineFaults, UartRead, UartWrite
from fpgaemu.uartcommand import WATCHDOG_CYCLES, EnableChange, UartCommand
from fpgaemu.uartsend import UartSend
from fpgalink.protocol import DEFAULT_FRAMING, Framing
from fpgalink.protocol.params import CHANNEL_A, CHANNEL_B

__all__ = ["Board", "BoardConfig", "ChannelIo", "Peripheral"]


@dataclass
class ChannelIo:
    """One motor channel's I/O blocks, as the processor sees them."""

    pwm: Pwm
    encoder: QuadratureEncoder
    #: the Hall current sensor's reading, A (the motor model keeps it current)
    current_a: float = 0.0


@dataclass
class BoardConfig:
    """Everything fixed at power-up. Mutable so a caller can fill it from options."""

    baud: int = DEFAULT_BAUD
    seed: int = 0
    framing: Framing = DEFAULT_FRAMING
    watchdog_cycles: int = WATCHDOG_CYCLES
    #: host → board line faults (``uartread``)
    rx_faults: LineFaults | None = None
    #: board → host line faults (``uartwrite``)
    tx_faults: LineFaults | None = None
    #: idle cycles ``uartwrite`` leaves after each stop bit when bytes go back to back: 0
    #: (the seed's uartwrite as modelled: one stop bit exactly), 2 for LiteX's PHY (1,002
    #: cycles a byte at 1 MBd), 1 for amaranth-stdio's (docs/emulator.md)
    tx_byte_gap: int = 0
    #: how ``uartread`` finds a start bit: ``edge`` (LiteX's) or ``level`` (a 16550's,
    #: verilog-uart's): :data:`fpgaemu.uart.UART_RX_MODES`
    uart_rx: str = "edge"


class Peripheral(Protocol):
    """Anything that attaches itself to the board's timeline and AXI bus."""

    def attach(self, board: Board) -> None: ...


class Board:
    """One emulated CmodA7 board. Attributes are named after the seed's modules."""

    def __init__(self, config: BoardConfig | None = None, **overrides: Any) -> None:
        config = BoardConfig() if config is None else config
        if overrides:
            config = dataclasses.replace(config, **overrides)
        self.config = config
        self.peripherals: dict[str, Peripheral] = {}
        #: the cycle of the last power-up (0, or the last :meth:`power_cycle`)
        self.powered_at = 0
        self.power_cycles = 0
        #: host bytes still on the RX line when the board power-cycled (lost with it)
        self.power_cycle_rx_lost = 0
        self._restart_at: list[int] = []
        #: TX bytes completed before a power cycle, still to be read by the host
        self._carried_tx: list[tuple[int, int]] = []
        self._power_up(0)

    def _power_up(self, cycle: int) -> None:
        """Every FPGA block in its power-up state, on a timeline that starts at ``cycle``
        (0 at first; a power cycle's moment after)."""
        config = self.config
        self.timeline = Timeline(config.seed)
        self.timeline.now = cycle
        self.blk_mem_gen_rx = BlockRam(BRAM_BYTES, "blk_mem_gen_rx")
        self.blk_mem_gen_tx = BlockRam(BRAM_BYTES, "blk_mem_gen_tx")
        self.uartcommand = UartCommand(
            self.timeline, self.blk_mem_gen_rx, config.framing, config.watchdog_cycles
        )
        self.uartread = UartRead(
            self.timeline, self.uartcommand.receive, config.baud, config.rx_faults,
            config.uart_rx,
        )
        self.uartwrite = UartWrite(self.timeline, config.baud, config.tx_faults,
                                   config.tx_byte_gap)
        self.uartsend = UartSend(
            self.timeline, self.blk_mem_gen_tx, self.uartwrite, config.framing
        )
        self.axi = AxiBus(
            self.timeline, self.uartcommand, self.uartsend, self.blk_mem_gen_rx,
            self.blk_mem_gen_tx,
        )
        self.timer = Timer(self.timeline)
        self.channels = {
            CHANNEL_A: ChannelIo(Pwm(), QuadratureEncoder()),
            CHANNEL_B: ChannelIo(Pwm(), QuadratureEncoder()),
        }
        # The PWM outputs are gated by global_enable in logic, before any software sees it.
        self.uartcommand.on_enable_change(self._gate_pwm)
        self._settlers: list[Callable[[int], None]] = []
        self._skippable: Callable[[], EventHandle | None] | None = None

    def _gate_pwm(self, change: EnableChange) -> None:
        for io in self.channels.values():
            io.pwm.set_global_enable(change.enabled, change.cycle)

    # --- composition ----------------------------------------------------------------------

    def add_peripheral(self, name: str, peripheral: Peripheral) -> Peripheral:
        """Register a module under ``name`` and let it wire itself (``attach``)."""
        if name in self.peripherals:
            raise ValueError(f"a peripheral named {name!r} is already attached")
        self.peripherals[name] = peripheral
        peripheral.attach(self)
        return peripheral

    def on_settle(self, settler: Callable[[int], None]) -> None:
        """``settler(cycle)`` brings a lazily integrated model (the wheels) up to ``cycle``
        whenever the processor samples its inputs."""
        self._settlers.append(settler)

    def settle(self, cycle: int) -> None:
        """Bring every lazily integrated model up to ``cycle`` before inputs are sampled."""
        for settler in self._settlers:
            settler(cycle)

    def set_skippable(self, source: Callable[[], EventHandle | None]) -> None:
        """``source()`` names a scheduled event that will change nothing observable (the
        firmware's next tick while the board is quiescent), or ``None``."""
        self._skippable = source

    @property
    def quiescent(self) -> bool:
        """The next timer tick is known to change nothing observable (see
        :meth:`set_skippable`)."""
        return self._skippable is not None and self._skippable() is not None

    def next_deadline(self) -> int | None:
        """The cycle of the next event that may change something a host could see (an event
        known to change nothing is not counted), or ``None`` when nothing is scheduled."""
        skip = self._skippable() if self._skippable is not None else None
        deadline = self.timeline.next_deadline_except(skip)
        if self._restart_at and (deadline is None or self._restart_at[0] < deadline):
            return self._restart_at[0]
        return deadline

    # --- power ----------------------------------------------------------------------------

    def schedule_power_cycle(self, cycle: int) -> None:
        """Power-cycle the board at ``cycle`` (a brown-out, a watchdog reset of the
        MicroBlaze, a re-flashed bitstream): see :meth:`power_cycle`."""
        if cycle < self.now:
            raise ValueError(f"cannot power-cycle at cycle {cycle}: the present is {self.now}")
        self._restart_at.append(cycle)
        self._restart_at.sort()

    def power_cycle(self) -> None:
        """The board restarts now: every FPGA block and the MicroBlaze software back to
        their power-up state — registers, both block RAMs, the watchdog and
        ``global_enable`` (low), the encoders' counters (0 at the wheels' present angles),
        the timer and the board's clock (``t_us`` from 0), the message counter (``00000``)
        and every parameter (the power-up values). The physical world goes on: a turning
        wheel keeps turning (coasting, its PWM at 0) and the robot's body with it. Host
        bytes the line had not finished delivering are lost; bytes the board finished
        sending before the cut stay readable, as they reached the host's UART.

        Each peripheral either carries over (the motors, the line's faults) or is replaced
        by its power-up self (the firmware): ``power_cycled()`` returns what to attach."""
        at = self.now
        self._carried_tx.extend(self.uartwrite.read_completed_timed())
        before = self.uartcommand.stats.bytes_received
        self.uartcommand.discard_from(at)
        self.power_cycle_rx_lost += before - self.uartcommand.stats.bytes_received
        peripherals = self.peripherals
        self._power_up(at)
        self.peripherals = {}
        self.powered_at = at
        self.power_cycles += 1
        for name, peripheral in peripherals.items():
            revive = getattr(peripheral, "power_cycled", None)
            self.add_peripheral(name, revive() if revive is not None else peripheral)

    # --- time -----------------------------------------------------------------------------

    @property
    def now(self) -> int:
        return self.timeline.now

    def run_until(self, cycle: int) -> None:
        restarts = self._restart_at
        while restarts and restarts[0] <= cycle:
            at = restarts.pop(0)
            if at > self.timeline.now:
                self.timeline.run_until(at)
                self.uartcommand.sync()
            self.power_cycle()
        self.timeline.run_until(cycle)
        self.uartcommand.sync()

    def run_for(self, seconds: float) -> None:
        self.run_until(self.timeline.now + seconds_to_cycles(seconds))

    def run_cycles(self, cycles: int) -> None:
        self.run_until(self.timeline.now + cycles)

    def schedule(
        self, cycle: int, callback: Callable[[int], None], *, late: bool = False
    ) -> EventHandle:
        return self.timeline.schedule(cycle, callback, late=late)

    # --- the host's end of the cable ------------------------------------------------------

    def host_write(self, data: bytes | bytearray | memoryview, cycle: int | None = None) -> int:
        """The host starts sending ``data`` on the RX pin at ``cycle`` (default now), queued
        behind bytes still on the line. Returns the cycle the last stop bit ends."""
        return self.uartread.transmit(data, cycle)

    def host_unplugged(self, cycle: int | None = None) -> int:
        """The host's cable comes out at ``cycle`` (default now): bytes it wrote that had not
        begun their start bit by then never reach the board. Returns how many were lost."""
        at = self.timeline.now if cycle is None else cycle
        line = self.uartread
        before = self.uartcommand.stats.bytes_received
        last = self.uartcommand.discard_from(at)
        lost = before - self.uartcommand.stats.bytes_received
        line.stats.dropped_bytes += lost
        line.line_free_at = max(at, last) if last is not None else at
        return lost

    def read_host_bytes(self, whole_runs: bool = False) -> bytes:
        """TX bytes whose stop bit has ended by now, not returned before; with
        ``whole_runs``, a run of bytes (a frame) only once it has ended whole
        (:meth:`UartWrite.read_completed_runs`)."""
        line = self.uartwrite
        fresh = line.read_completed_runs() if whole_runs else line.read_completed()
        if self._carried_tx:
            return bytes(b for b, _ in self._take_carried()) + fresh
        return fresh

    def read_host_bytes_timed(self) -> list[tuple[int, int]]:
        """As :meth:`read_host_bytes`, as ``(byte, completion cycle)`` pairs."""
        if self._carried_tx:
            return self._take_carried() + self.uartwrite.read_completed_timed()
        return self.uartwrite.read_completed_timed()

    def _take_carried(self) -> list[tuple[int, int]]:
        carried, self._carried_tx = self._carried_tx, []
        return carried

    @property
    def global_enable(self) -> bool:
        return self.axi.global_enable

    @property
    def cycles_per_byte(self) -> int:
        return self.uartread.cycles_per_byte
