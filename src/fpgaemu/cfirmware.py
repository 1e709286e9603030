"""The C firmware core (``firmware/``) running in the emulator in place of the Python model of
the MicroBlaze software (:mod:`fpgaemu.firmware`): ``build_board(firmware="c")``,
``fpgaemu serve --firmware c``, ``emu://?firmware=c``.

Only the software is swapped. Every HAL call the C makes (``firmware/hal.h``) lands on the
same cycle-level models the Python firmware drives — the AXI port to ``uartcommand`` and
``uartsend`` and their block RAMs, the timer, the PWM stages, the encoders, the Hall sensors
and the FPGA's controller modules — at the cycle of the interrupt being handled; the
emulator's own bookkeeping (the SPEC §7 timing report, skipping quiescent ticks) is kept
here, as the Python firmware keeps it.

The C is built on first use with the system C compiler (:mod:`fpgaemu.cbuild`, cached) from
the firmware's sources and the protocol code the generator writes: the generator runs as a
program (``python -m fpgalink.codegen c DIR``), the emulator never imports it.
"""

from __future__ import annotations

import functools
import hashlib
import os
import shutil
import struct
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import fpgalink.protocol
from fpgaemu.board import Board
from fpgaemu.cbuild import CBuildError, SharedLibrary, build_shared, cache_dir, load
from fpgaemu.firmware import (
    ALIVE_PERIOD_CYCLES,
    HW_CURRENT_KP,
    SW_CURRENT_KP,
    FirmwareStats,
    emulated_serial,
)
from fpgaemu.hwcontrol import Coefficients, HardwareController, LoopInput
from fpgaemu.motor import MotorConstants
from fpgaemu.pid import PidGains
from fpgaemu.timeline import EventHandle
from fpgaemu.timing import FrameBooking, TimingReport
from fpgaemu.uartcommand import EnableChange, RxInterrupt
from fpgaemu.uartsend import TxDone
from fpgalink.protocol import PARAMETERS, NackReason, Param, ParamType, Scope, resolve
from fpgalink.protocol.exitcodes import NotInstalled
from fpgalink.protocol.params import BOARD, CHANNEL_A, CHANNEL_B

__all__ = ["CFirmware", "CFirmwareUnavailable", "attach_c_firmware", "firmware_sources",
           "load_firmware"]

_MOTOR = MotorConstants()
_F32 = struct.Struct("<f")
_I32 = struct.Struct("<i")
_U32 = struct.Struct("<I")


class CFirmwareUnavailable(CBuildError):
    """The C firmware cannot run here (no C compiler, no cffi, or its sources are missing)."""


class CFirmwareNotInstalled(CFirmwareUnavailable, NotInstalled):
    """The C firmware cannot run here for want of a part: a C compiler, or cffi."""


def firmware_sources() -> Path:
    """The firmware core's directory: inside the installed package, or ``firmware/`` of the
    source tree this package runs from."""
    here = Path(__file__).resolve().parent
    for candidate in (here / "_firmware", here.parents[1] / "firmware"):
        if (candidate / "firmware.c").exists():
            return candidate
    raise CFirmwareUnavailable(f"the C firmware's sources are not installed (looked in "
                               f"{here / '_firmware'} and {here.parents[1] / 'firmware'})")


def _generator_inputs() -> list[Path]:
    """The files the generated protocol C is a function of (read, never imported)."""
    package = Path(fpgalink.protocol.__file__).resolve().parent.parent
    codegen = package / "codegen"
    return sorted([*(package / "protocol").glob("*.py"), *codegen.glob("*.py"),
                   *(codegen / "templates").glob("*")])


def _generated_protocol() -> Path:
    """The generated protocol C for these declarations (generated once, then cached)."""
    digest = hashlib.sha256()
    for path in _generator_inputs():
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    target = cache_dir() / f"protocol-{digest.hexdigest()[:20]}"
    if (target / "fpgalink_protocol.h").exists():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{target.name}-", dir=target.parent))
    try:
        done = subprocess.run([sys.executable, "-m", "fpgalink.codegen", "c", str(work)],
                              capture_output=True, text=True, timeout=120, check=False,
                              env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})
        if done.returncode != 0:
            raise CFirmwareUnavailable(f"the protocol code generator failed: "
                                       f"{done.stderr.strip()[:2000]}")
        try:
            work.rename(target)
        except OSError:
            if not (target / "fpgalink_protocol.h").exists():
                raise
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)
    return target


@functools.cache
def _library() -> SharedLibrary:
    sources = firmware_sources()
    generated = _generated_protocol()
    return build_shared(
        "fwcosim",
        [generated / "fpgalink_protocol.c", sources / "control.c", sources / "firmware.c"],
        [sources / "firmware.h"], [generated, sources])


@functools.cache
def load_firmware() -> tuple[Any, Any]:
    """``(ffi, lib)`` of the C firmware core, built on first use.
    :class:`CFirmwareUnavailable` when it cannot be."""
    try:
        return load(_library())
    except CFirmwareUnavailable:
        raise
    except CBuildError as exc:
        kind = CFirmwareNotInstalled if isinstance(exc, NotInstalled) else CFirmwareUnavailable
        raise kind(f"the C firmware cannot run here: {exc}") from None


# --- views of the C state, shaped as the Python firmware's ------------------------------------


def _slots() -> dict[tuple[int, int], int]:
    """(parameter id, channel) → store slot, in the generated table's order."""
    slots: dict[tuple[int, int], int] = {}
    slot = 0
    for param in PARAMETERS:
        if param.scope is Scope.BOARD:
            slots[(param.id, BOARD)] = slot
            slot += 1
        else:
            slots[(param.id, CHANNEL_A)] = slot
            slots[(param.id, CHANNEL_B)] = slot + 1
            slot += 2
    return slots


_SLOTS = _slots()
_BY_ID = {p.id: p for p in PARAMETERS}


class _Values(Mapping[tuple[int, int], int | float]):
    """``{(param id, channel): value in force}``, read from the C store."""

    def __init__(self, state: Any) -> None:
        self._state = state

    def __getitem__(self, key: tuple[int, int]) -> int | float:
        value = self._state.values[_SLOTS[key]]
        return int(value.i) if _BY_ID[key[0]].type is ParamType.INT else float(value.f)

    def __iter__(self) -> Iterator[tuple[int, int]]:
        return iter(_SLOTS)

    def __len__(self) -> int:
        return len(_SLOTS)


class CPid:
    """One of the C firmware's software PIDs, as :class:`fpgaemu.pid.Pid` reads."""

    def __init__(self, pid: Any) -> None:
        self._pid = pid

    @property
    def gains(self) -> PidGains:
        g = self._pid.gains
        return PidGains(float(g.kp), float(g.ti), float(g.td))

    @property
    def integral(self) -> float:
        return float(self._pid.integral)

    @property
    def saturated(self) -> bool:
        return bool(self._pid.saturated)

    @property
    def limit(self) -> int:
        return int(self._pid.limit)

    @property
    def at_rest(self) -> bool:
        p = self._pid
        return (p.integral == 0.0 and p.derivative == 0.0 and not p.has_last
                and not p.saturated)


class CChannel:
    """One channel's state in the C firmware, as :class:`fpgaemu.firmware.Channel` reads."""

    def __init__(self, channel: Any, hardware: HardwareController) -> None:
        self._channel = channel
        self.pid = CPid(channel.speed_pid)
        self.current_pid = CPid(channel.current_pid)
        self.hardware: HardwareController | None = hardware

    @property
    def reference(self) -> float:
        return float(self._channel.reference)

    @property
    def speed(self) -> float:
        return float(self._channel.speed)

    @property
    def current(self) -> float:
        return float(self._channel.current)

    @property
    def position(self) -> int:
        return int(self._channel.position)


class _WireCrcView:
    def __init__(self, state: Any) -> None:
        self._state = state

    @property
    def on(self) -> bool:
        return bool(self._state.crc_on)

    @property
    def failures(self) -> int:
        return int(self._state.stats.crc_failures)


# --- the peripheral ---------------------------------------------------------------------------


class CFirmware:
    """The C core attached to a board. Its state (parameters, controllers, counters) lives in
    C and is read through views shaped as :class:`fpgaemu.firmware.Firmware`'s, so the
    emulator's tests run against either."""

    def __init__(self, settings: dict[str, Any] | None = None) -> None:
        self._ffi, self._lib = load_firmware()
        self._state = self._ffi.new("fw_state *")
        self._pending_settings = dict(settings or {})
        self._errors: list[BaseException] = []
        self._hal = self._ffi.new("fw_hal *")
        self._callbacks: list[Any] = []
        self._bind_hal()
        self.values: Mapping[tuple[int, int], int | float] = _Values(self._state)
        self.wire_crc = _WireCrcView(self._state)
        #: the frames on the wire, booked into the timing report once done
        self._frames = FrameBooking()
        self._timing = self._frames.report
        self._board: Board | None = None
        self._hardware: dict[int, HardwareController] = {}
        self.channels: dict[int, CChannel] = {}
        self.skip_quiescent_ticks = True
        self.last_tick = 0
        self.language = "c"

    # --- the HAL, bound to this board's models ----------------------------------------------

    def _bind_hal(self) -> None:
        ffi, hal = self._ffi, self._hal
        for name, function in (
            ("rx_copy", self._rx_copy), ("rx_ack", self._rx_ack), ("tx_busy", self._tx_busy),
            ("tx_send", self._tx_send), ("tx_done_interrupt", self._tx_done_interrupt),
            ("timer_start", self._timer_start),
            ("timer_set_period_ms", self._timer_set_period_ms),
            ("alive_timer_start", self._alive_timer_start), ("time_us", self._time_us),
            ("sample", self._sample), ("pwm_write", self._pwm_write),
            ("pwm_read", self._pwm_read), ("encoder_configure", self._encoder_configure),
            ("hwpid_configure", self._hwpid_configure),
            ("hwpid_reference", self._hwpid_reference), ("hwpid_run", self._hwpid_run),
            ("hwpid_saturated", self._hwpid_saturated),
        ):
            callback = ffi.callback(ffi.typeof(getattr(hal, name)), function,
                                    onerror=self._callback_failed)
            self._callbacks.append(callback)  # cffi does not keep it alive for us
            setattr(hal, name, callback)

    def _callback_failed(self, exc_type: type[BaseException], exc: BaseException,
                         traceback: Any) -> None:
        # A Python error inside a HAL call cannot cross the C frames: kept, raised after.
        self._errors.append(exc)

    def _check(self) -> None:
        if self._errors:
            error = self._errors[0]
            self._errors.clear()
            raise error

    @property
    def board(self) -> Board:
        assert self._board is not None, "the firmware is not attached to a board"
        return self._board

    def _rx_copy(self, context: Any, start: int, length: int, content: Any) -> None:
        self._ffi.memmove(content, self.board.axi.read_rx(start, length), length)

    def _rx_ack(self, context: Any, start: int) -> None:
        self.board.axi.ack_rx(start)

    def _tx_busy(self, context: Any) -> bool:
        return self.board.axi.tx_busy

    def _tx_send(self, context: Any, content: Any, length: int, telemetry: bool,
                 tag: int) -> None:
        axi = self.board.axi
        accepted = axi.send_tx(bytes(self._ffi.buffer(content, length)))
        assert accepted, "uartsend refused a strobe while idle"
        uartsend = axi.uartsend
        self._frames.started(tag if telemetry else None, uartsend.busy_until,
                             uartsend.frame_wire_bytes)

    def _tx_done_interrupt(self, context: Any) -> None:
        self.board.axi.on_next_tx_done(self._on_tx_done)

    def _timer_start(self, context: Any) -> None:
        board = self.board
        board.timer.start(board.now)

    def _timer_set_period_ms(self, context: Any, period_ms: int) -> None:
        board = self.board
        self._frames.report_at(board)  # frames done so far against the old period
        board.timer.set_period_ms(period_ms)

    def _alive_timer_start(self, context: Any) -> None:
        board = self.board
        board.schedule(board.now + ALIVE_PERIOD_CYCLES, self._on_alive)

    def _time_us(self, context: Any) -> int:
        # The board's clock counts from its power-up (a power cycle starts it again).
        return ((self.board.now - self.board.powered_at) // 100) & 0xFFFF_FFFF

    def _sample(self, context: Any, channel: int, out: Any) -> None:
        board = self.board
        io = board.channels[channel]
        encoder = io.encoder
        out.speed = encoder.firmware_reader.sample(board.now)
        out.position = encoder.position
        out.current = io.current_a
        out.end_stop = encoder.end_stop
        out.pwm_enabled = io.pwm.global_enable

    def _pwm_write(self, context: Any, channel: int, duty: int) -> None:
        board = self.board
        board.channels[channel].pwm.write_duty(duty, board.now)

    def _pwm_read(self, context: Any, channel: int) -> int:
        return self.board.channels[channel].pwm.duty_register

    def _encoder_configure(self, context: Any, channel: int, pulses: int,
                           direction: int) -> None:
        board = self.board
        board.settle(board.now)  # the count restarts from the wheel's angle now
        board.channels[channel].encoder.configure(pulses, direction)

    def _hwpid_configure(self, context: Any, channel: int, loop: int, kp: int, ki: int,
                         kd: int, alpha: int, limit: int) -> None:
        hardware = self._hardware[channel]
        hardware.loop = LoopInput.CURRENT if loop else LoopInput.SPEED
        hardware.coefficients = Coefficients(kp, ki, kd, alpha)
        hardware.limit = limit

    def _hwpid_reference(self, context: Any, channel: int, reference: int) -> None:
        self._hardware[channel].reference = reference

    def _hwpid_run(self, context: Any, channel: int, run: bool) -> None:
        hardware = self._hardware[channel]
        if run:
            hardware.start(self.board.now)
        else:
            hardware.stop()

    def _hwpid_saturated(self, context: Any, channel: int) -> bool:
        return self._hardware[channel].saturated

    # --- wiring ---------------------------------------------------------------------------

    def power_cycled(self) -> CFirmware:
        """The core after a power cycle: a fresh state, the same power-up settings."""
        firmware = CFirmware(self._pending_settings)
        firmware.skip_quiescent_ticks = self.skip_quiescent_ticks
        return firmware

    def attach(self, board: Board) -> None:
        self._board = board
        lib, state = self._lib, self._state
        axi = board.axi
        axi.on_rx_interrupt(self._on_rx)
        axi.on_global_enable(self._on_enable)
        self._timing.started_cycle = board.now
        # The FPGA's controller modules are hardware: there from power-up, idle until run.
        for code in (CHANNEL_A, CHANNEL_B):
            self._hardware[code] = HardwareController(board, board.channels[code])
        config = self._ffi.new("fw_config *")
        config.sw_current_kp = SW_CURRENT_KP
        config.hw_current_kp = HW_CURRENT_KP
        config.electrical_tau = _MOTOR.inductance_h / _MOTOR.resistance_ohm
        config.serial = emulated_serial(board.config.seed)
        lib.fw_init(state, self._hal, self._ffi.NULL, config)
        self._check()
        for code in (CHANNEL_A, CHANNEL_B):
            self.channels[code] = CChannel(state.channels[code - 1], self._hardware[code])
        for name, value in self._pending_settings.items():
            param, channel = resolve(name)
            error = self._setting(param, channel, value)
            if error:
                raise ValueError(f"initial {name} = {value!r}: {NackReason(error).text}")
        board.timer.on_interrupt(self._on_tick)
        lib.fw_start(state)
        self._check()
        board.set_skippable(self.skippable_event)

    def _setting(self, param: Param, channel: int, value: object) -> int:
        """An initial value, checked as a PS would be (its PN code, or 0)."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            return int(NackReason.WRONG_TYPE)
        if param.type is ParamType.INT:
            if isinstance(value, float) and not value.is_integer():
                return int(NackReason.WRONG_TYPE)
            if not -(2**31) <= value < 2**31:
                return int(NackReason.OUT_OF_RANGE)
            raw = _U32.unpack(_I32.pack(int(value)))[0]
        else:
            try:
                raw = _U32.unpack(_F32.pack(float(value)))[0]
            except OverflowError:
                return int(NackReason.OUT_OF_RANGE)
        error = int(self._lib.fw_setting(self._state, param.id, channel, int(param.type), raw))
        self._check()
        return error

    # --- interrupts -----------------------------------------------------------------------

    def _on_rx(self, irq: RxInterrupt) -> None:
        self._lib.fw_on_rx(self._state, irq.start_address, irq.length)
        self._check()

    def _on_enable(self, change: EnableChange) -> None:
        self._lib.fw_on_enable(self._state, change.enabled)
        self._check()

    def _on_tx_done(self, event: TxDone) -> None:
        self._lib.fw_on_tx_done(self._state)
        self._check()

    def _on_alive(self, cycle: int) -> None:
        self._lib.fw_on_alive(self._state)
        self._check()
        self.board.schedule(cycle + ALIVE_PERIOD_CYCLES, self._on_alive)

    def _on_tick(self, cycle: int) -> None:
        self.last_tick = cycle
        if self._frames.due(cycle):
            self._frames.book(cycle, self.board.timer.period_cycles)
        if self.skip_quiescent_ticks and not self._state.enabled and self.quiescent:
            self._timing.periods += 1  # what a full tick would do, no more
            return
        board = self.board
        board.settle(cycle)
        stats = self._state.stats
        dropped = stats.telemetry_dropped
        self._lib.fw_on_tick(self._state, cycle)
        self._check()
        self._timing.periods += 1
        if stats.telemetry_dropped != dropped:
            self._timing.record_miss(cycle, None)

    # --- what the emulator asks of a firmware -----------------------------------------------

    @property
    def quiescent(self) -> bool:
        """As :attr:`fpgaemu.firmware.Firmware.quiescent`: a tick now would change nothing."""
        if not self._lib.fw_quiescent(self._state):
            return False
        board = self.board
        for code, ch in self.channels.items():
            io = board.channels[code]
            if (io.pwm.duty_register or self._hardware[code].running
                    or not io.encoder.settled or ch.position != io.encoder.position):
                return False
        motors = board.peripherals.get("motors")
        return motors is None or bool(getattr(motors, "at_rest", False))

    def skippable_event(self) -> EventHandle | None:
        if not self.skip_quiescent_ticks or self._state.enabled or not self.quiescent:
            return None
        return self.board.timer.handle

    @property
    def timing(self) -> TimingReport:
        return self._frames.report_at(self.board)

    def budget_report(self) -> dict[str, Any]:
        return self.timing.summary(self.board)

    @property
    def stats(self) -> FirmwareStats:
        s = self._state.stats
        return FirmwareStats(
            messages=s.messages, malformed=s.malformed, unknown=s.unknown,
            param_sets=s.param_sets, param_gets=s.param_gets, refusals=s.refusals,
            references=s.references, invalid_references=s.invalid_references,
            telemetry_sent=s.telemetry_sent, telemetry_dropped=s.telemetry_dropped,
            alive_sent=s.alive_sent, crc_failures=s.crc_failures)

    def channel(self, code: int) -> CChannel:
        return self.channels[code]

    def value(self, name: str, channel: int | str | None = None) -> int | float:
        param, code = resolve(name, channel)
        return self.values[(param.id, code)]

    def mode(self, code: int) -> int:
        return int(self.values[(4, code)])


def attach_c_firmware(board: Board, settings: dict[str, Any] | None = None) -> CFirmware:
    firmware = CFirmware(settings)
    board.add_peripheral("firmware", firmware)
    return firmware
