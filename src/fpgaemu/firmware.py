"""The MicroBlaze software (seed §3.2–3.3), written against the board's registers only: the
AXI port to the UART logic, the timer, and each channel's PWM, encoder and current sensor.

* RX interrupt: read the frame from the RX block RAM, acknowledge the half, handle it:
  ``PS`` (validate, apply, recompute, echo ``PA`` or answer ``PN``), ``PG`` (``PA``),
  ``RV`` (references). Malformed and unknown messages are counted and ignored.
* Timer interrupt every TsTimerPeriod ms: sample encoders and current sensors, run the
  controllers, write the PWM registers, and send ``TM`` while GetDataPeriodical = 1.
* ``E`` every 300 ms, enabled or not.
* ``global_enable`` falling (``RD`` or watchdog): integrators reset, references cleared.
* The optional wire CRC (:mod:`fpgalink.protocol.crc`): off at power-up; ``WireCrc`` = 1
  switches it on, the ``PA`` already carrying it; frames failing the check are counted in
  :attr:`FirmwareStats.crc_failures` and dropped. ``Firmware(wire_crc=False)`` is a board
  from before the extension: it answers ``PN`` 1 for the parameter.
* Board identity (:mod:`fpgalink.protocol.identity`): ``IQ`` is answered with ``IA``: the
  query's nonce, the hash of the declaration this firmware runs (this package's), the
  firmware's version (:data:`FIRMWARE_VERSION`, the C core's ``FW_VERSION_*``) and build,
  and the board's serial (:func:`emulated_serial` of the board's seed). ``Firmware(
  identity=False)`` is a seed board: ``IQ`` is an unknown message, counted, unanswered;
  ``Firmware(declarations=H)`` answers with the hash ``H`` instead, as a firmware generated
  from another declaration would (for a host's refusal to be tried; the wire it speaks is
  still this one).

Controller modes (parameter 4, per channel):

* 0 — software speed PID at each timer tick (parameters 8–10, PWM counts per deg/s);
* 1 — hardware speed PID: the same gains, computed by the FPGA's controller module
  (:mod:`fpgaemu.hwcontrol`) in fixed point at 10 kHz, independent of the timer;
* 2 — software current PID at each timer tick: ``RV`` carries torque (N·m), the current
  reference is torque / ``TorqueCoef``, and the firmware's own current-loop gains
  (:data:`SW_CURRENT_KP`, Ti = max(L/R, the timer period)) drive the duty;
* 3 — hardware current PID: the module's current loop (:data:`HW_CURRENT_KP`, Ti = L/R)
  at 10 kHz on the Hall sensor's reading.

The current-loop gains are the firmware's, not parameters (SPEC §5 has gains for the speed
loop only), derived from the motor's electrical model. Changing a channel's controller
while enabled is allowed: that channel's reference clears to 0 (a speed and a torque are
not the same thing) and the new controller starts from rest. ``TM`` reports the reference
in the mode's unit and bit 2 when the active controller's output is clamped.

Power-up values come from the parameter table's ``default`` column.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import isfinite
from typing import Any, Final

from fpgaemu.axi import TxQueue
from fpgaemu.board import Board
from fpgaemu.hwcontrol import HardwareController, LoopInput
from fpgaemu.motor import MotorConstants
from fpgaemu.pid import Pid, PidGains
from fpgaemu.pwm import MAX_DUTY
from fpgaemu.timeline import CLOCK_HZ, EventHandle, ms, us
from fpgaemu.timing import FrameBooking, TimingReport
from fpgaemu.uartcommand import EnableChange, RxInterrupt
from fpgalink.protocol import (
    PARAMETERS,
    WIRE_CRC_PARAM,
    ChannelTelemetry,
    CounterTracker,
    Malformed,
    NackReason,
    Param,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    ParamType,
    References,
    Scope,
    SendCounter,
    TelemetryFlags,
    encode_message,
    encode_telemetry,
    float32,
    parse_content,
    resolve,
)
from fpgalink.protocol.catalogue import IdentityAnswer, IdentityQuery
from fpgalink.protocol.crc import HANDSHAKE_WITH_CRC, BoardWireCrc, append_crc
from fpgalink.protocol.identity import declarations_hash
from fpgalink.protocol.params import BOARD, CHANNEL_A, CHANNEL_B

__all__ = ["FIRMWARE_BUILD", "FIRMWARE_VERSION", "Firmware", "FirmwareStats", "attach_firmware",
           "emulated_serial"]

#: The firmware's version, as ``IA`` reports it: 1.0 was the seed's (no ``IQ``); 1.1 answers
#: it. The C core says the same (``FW_VERSION_*`` in firmware/firmware.h; a test holds the
#: two to it).
FIRMWARE_VERSION = (1, 1, 0)
#: The build ``IA`` reports: 0, not set (a real board's build sets ``FW_BUILD`` to its
#: commit).
FIRMWARE_BUILD = 0
#: An emulated board's serial: this, plus its seed (a real board's is the FPGA's 57-bit
#: device DNA).
_EMULATED_SERIAL_BASE = 0x00E5_EED0_0000_0000

ALIVE_PERIOD_CYCLES: Final = ms(300)
#: ActiveController values
SPEED_SW: Final = 0
SPEED_HW: Final = 1
CURRENT_SW: Final = 2
CURRENT_HW: Final = 3
HARDWARE_MODES: Final = (SPEED_HW, CURRENT_HW)
_MOTOR: Final = MotorConstants()
_CYCLES_PER_US: Final = us(1)
# Plain ints: the flag word is built every tick, and IntFlag arithmetic is slow.
_ENABLE: Final = int(TelemetryFlags.ENABLE)
_END_STOP: Final = int(TelemetryFlags.END_STOP)
_SATURATED: Final = int(TelemetryFlags.SATURATED)
#: Duty (PWM counts) to current (A) at stall, the current loop's plant gain.
_AMPS_PER_COUNT: Final = _MOTOR.supply_v / _MOTOR.resistance_ohm / MAX_DUTY
_ELECTRICAL_TAU: Final = _MOTOR.inductance_h / _MOTOR.resistance_ohm
#: Current-loop gains, PWM counts per A: a loop gain of 0.5 per tick in software (stable at
#: any timer period), 2 in hardware (crossover ≈ 2,000 rad/s at 10 kHz).
SW_CURRENT_KP: Final = 0.5 / _AMPS_PER_COUNT
HW_CURRENT_KP: Final = 2.0 / _AMPS_PER_COUNT


class Channel:
    """The software's state for one motor channel: its controllers, reference and the
    latest samples of its inputs (and, once attached, the FPGA controller module)."""

    def __init__(self, gains: PidGains, mode: int) -> None:
        self.mode = mode  #: the ActiveController in force (parameter 4)
        self.pid = Pid(gains)
        self.current_pid = Pid(PidGains(SW_CURRENT_KP, _ELECTRICAL_TAU, 0.0))
        self.hardware: HardwareController | None = None
        self.reference = 0.0  #: deg/s, or N·m under current control
        self.speed = 0.0
        self.current = 0.0
        self.position = 0


@dataclass(slots=True)
class FirmwareStats:
    messages: int = 0
    malformed: int = 0
    unknown: int = 0
    param_sets: int = 0
    param_gets: int = 0
    refusals: int = 0
    references: int = 0
    #: RV messages refused for a non-finite reference (the references in force stay)
    invalid_references: int = 0
    telemetry_sent: int = 0
    telemetry_dropped: int = 0  #: the TX queue was full
    alive_sent: int = 0
    crc_failures: int = 0  #: frames dropped for a bad wire CRC


def emulated_serial(seed: int) -> int:
    """The serial an emulated board built with ``seed`` reports in ``IA``."""
    return _EMULATED_SERIAL_BASE | (seed & 0xFFFF_FFFF)


class Firmware:
    def __init__(self, settings: dict[str, Any] | None = None, *, wire_crc: bool = True,
                 identity: bool = True, declarations: int | None = None) -> None:
        #: answers ``IQ`` (False: a seed board, which does not know the message)
        self.identity = identity
        #: the declaration hash ``IA`` says (``None``: this package's, the one it runs)
        self.declarations = declarations
        #: the parameters this firmware knows (without WireCrc: a board older than the CRC)
        self.parameters = {p.id: p for p in PARAMETERS
                           if wire_crc or p.id != WIRE_CRC_PARAM}
        self.wire_crc = BoardWireCrc()
        self.values: dict[tuple[int, int], int | float] = {}
        for param in self.parameters.values():
            for channel in _channels_of(param):
                self.values[(param.id, channel)] = _stored(param, param.default)
        self.channels = {code: Channel(self._gains(code), int(self.values[(4, code)]))
                         for code in (CHANNEL_A, CHANNEL_B)}
        #: GetDataPeriodical = 1: a TM at every tick
        self.telemetry_on = self.values[(2, BOARD)] == 1
        self.stats = FirmwareStats()
        #: the frames on the wire, booked into the timing report once done
        self._frames = FrameBooking()
        self._timing = self._frames.report
        self.host_counter = CounterTracker()
        self._counter = SendCounter()
        self._pending_settings = dict(settings or {})
        self._powered_at = 0  #: the cycle the board powered up: t_us counts from it
        self._board: Board | None = None
        self._enabled = False
        #: run a quiescent tick as a count only (off: the full tick, for equivalence tests)
        self.skip_quiescent_ticks = True
        self.last_tick = 0  #: the cycle of the last timer interrupt

    def _gains(self, code: int) -> PidGains:
        values = self.values
        return PidGains(float(values[(8, code)]), float(values[(9, code)]),
                        float(values[(10, code)]))

    @property
    def board(self) -> Board:
        assert self._board is not None, "the firmware is not attached to a board"
        return self._board

    # --- wiring ---------------------------------------------------------------------------

    def power_cycled(self) -> Firmware:
        """The software after a power cycle: started afresh with the same power-up
        settings (what was flashed), nothing of this run's state."""
        firmware = Firmware(self._pending_settings, identity=self.identity,
                            declarations=self.declarations)
        firmware.skip_quiescent_ticks = self.skip_quiescent_ticks
        return firmware

    def attach(self, board: Board) -> None:
        self._board = board
        self._powered_at = board.powered_at
        axi = board.axi
        axi.on_rx_interrupt(self._on_rx)
        axi.on_global_enable(self._on_enable)
        self.tx = TxQueue(axi, depth=8, on_start=self._frames.started)
        now = board.now
        self._timing.started_cycle = now
        for param in self.parameters.values():
            for channel in _channels_of(param):
                self._apply(param, channel, self.values[(param.id, channel)])
        for name, value in self._pending_settings.items():
            param, channel = resolve(name)
            error = self._check(param, channel, int(param.type), value)
            if error is not None:
                raise ValueError(f"initial {name} = {value!r}: {NackReason(error).text}")
            self._apply(param, channel, _stored(param, value))
        for code, ch in self.channels.items():
            ch.hardware = HardwareController(board, board.channels[code])
            self._configure_hardware(code)
        board.timer.on_interrupt(self._on_tick)
        board.timer.start(now)
        board.set_skippable(self.skippable_event)
        board.schedule(now + ALIVE_PERIOD_CYCLES, self._on_alive)

    @property
    def timing(self) -> TimingReport:
        """How the output fitted the timer periods, up to now (SPEC §7)."""
        return self._frames.report_at(self.board)

    def budget_report(self) -> dict[str, Any]:
        """SPEC §7 from this run (see :meth:`fpgaemu.timing.TimingReport.summary`)."""
        return self.timing.summary(self.board)

    def channel(self, code: int) -> Channel:
        return self.channels[code]

    def value(self, name: str, channel: int | str | None = None) -> int | float:
        param, code = resolve(name, channel)
        return self.values[(param.id, code)]

    # --- sending --------------------------------------------------------------------------

    def _send(self, message: Any, kind: str) -> bool:
        """Send or queue a message other than ``TM`` (the tick sends those itself)."""
        if kind == "E":
            return self.tx.send(b"E")
        return self.tx.send(self.wire_crc.send(encode_message(message, self._counter.take())))

    def _on_alive(self, cycle: int) -> None:
        if self._send(None, "E"):
            self.stats.alive_sent += 1
        assert self._board is not None
        self._board.schedule(cycle + ALIVE_PERIOD_CYCLES, self._on_alive)

    # --- receiving ------------------------------------------------------------------------

    def _on_rx(self, irq: RxInterrupt) -> None:
        assert self._board is not None
        axi = self._board.axi
        content = axi.take_rx(irq.start_address, irq.length)
        wire_crc = self.wire_crc
        if wire_crc.on or len(content) in HANDSHAKE_WITH_CRC:
            checked = wire_crc.receive(content)
            if checked is None:
                self.stats.crc_failures += 1
                return
            content = checked
        message = parse_content(content)
        self.stats.messages += 1
        counter = getattr(message, "counter", None)
        # The next expected counter (nearly always) is booked without the full observation.
        if counter is not None and not self.host_counter.observe_in_order(counter):
            self.host_counter.observe(counter)
        if isinstance(message, References):
            # Only the next timer tick reads the references, so the wheels need not be
            # brought up to this cycle. A non-finite reference is refused whole, as a
            # malformed message is: nothing a broken host sends may reach a controller.
            ref_a, ref_b = message.ref_a, message.ref_b
            if isfinite(ref_a) and isfinite(ref_b):
                self.stats.references += 1
                # Both channels written out: one of these arrives every millisecond.
                channel_a, channel_b = self.channels[CHANNEL_A], self.channels[CHANNEL_B]
                channel_a.reference = ref_a
                channel_b.reference = ref_b
                if channel_a.mode in HARDWARE_MODES:
                    self._write_hardware_reference(CHANNEL_A)
                if channel_b.mode in HARDWARE_MODES:
                    self._write_hardware_reference(CHANNEL_B)
            else:
                self.stats.invalid_references += 1
        elif isinstance(message, ParamSet):
            self.stats.param_sets += 1
            self._handle_set(message)
        elif isinstance(message, ParamGet):
            self.stats.param_gets += 1
            self._handle_get(message)
        elif isinstance(message, IdentityQuery) and self.identity:
            declarations = declarations_hash() if self.declarations is None \
                else self.declarations
            self._send(IdentityAnswer(message.nonce, declarations, *FIRMWARE_VERSION,
                                      FIRMWARE_BUILD, emulated_serial(self.board.config.seed)),
                       "IA")
        elif isinstance(message, Malformed):
            self.stats.malformed += 1
        else:
            self.stats.unknown += 1

    def _check(self, param: Param, channel: int, value_type: int, value: object) -> int | None:
        """The ``PN`` code for this request, or None when it is acceptable."""
        if not param.check_channel(channel):
            return NackReason.BAD_CHANNEL
        if value_type != param.type:
            return NackReason.WRONG_TYPE
        if not isinstance(value, int | float) or isinstance(value, bool):
            return NackReason.WRONG_TYPE
        if param.type is ParamType.INT and isinstance(value, float) and not value.is_integer():
            return NackReason.WRONG_TYPE
        if isinstance(value, float) and not isfinite(value):
            return NackReason.OUT_OF_RANGE
        if not param.in_range(value):
            return NackReason.OUT_OF_RANGE
        return None

    def _handle_set(self, message: ParamSet) -> None:
        param = self.parameters.get(message.param_id)
        if param is None:
            self._refuse(message.param_id, message.channel, NackReason.UNKNOWN_ID)
            return
        error = self._check(param, message.channel, message.value_type, message.value)
        if error is not None:
            self._refuse(message.param_id, message.channel, error)
            return
        self._apply(param, message.channel, _stored(param, message.value))
        self._acknowledge(param, message.channel)

    def _handle_get(self, message: ParamGet) -> None:
        param = self.parameters.get(message.param_id)
        if param is None:
            self._refuse(message.param_id, message.channel, NackReason.UNKNOWN_ID)
        elif not param.check_channel(message.channel):
            self._refuse(message.param_id, message.channel, NackReason.BAD_CHANNEL)
        else:
            self._acknowledge(param, message.channel)

    def _refuse(self, param_id: int, channel: int, error: int) -> None:
        self.stats.refusals += 1
        self._send(ParamNack(param_id, channel, error), "PN")

    def _acknowledge(self, param: Param, channel: int) -> None:
        value = self.values[(param.id, channel)]
        self._send(ParamAck(param.id, channel, int(param.type), value), "PA")

    def _apply(self, param: Param, channel: int, value: int | float) -> None:
        """Store and recompute whatever depends on the parameter."""
        self.values[(param.id, channel)] = value
        if param.id == 2:
            self.telemetry_on = value == 1
        elif param.id == 4:
            self.channels[channel].mode = int(value)
        if self._board is None:
            return  # applied to the hardware at attach
        if param.id == 1:
            self._frames.report_at(self.board)  # frames done so far against the old period
            self.board.timer.set_period_ms(int(value))
        elif param.id == WIRE_CRC_PARAM:
            # Before the PA goes out: the confirmation is the first message in the new form.
            self.wire_crc.on = value == 1
        elif param.scope is Scope.CHANNEL:
            ch = self.channels[channel]
            if param.id == 4:
                self._change_controller(channel)
            elif param.id == 5:
                ch.pid.limit = ch.current_pid.limit = int(value)
                self._configure_hardware(channel)
            elif param.id in (6, 7):
                board = self.board
                board.settle(board.now)  # the count restarts from the wheel's angle now
                board.channels[channel].encoder.configure(
                    int(self.values[(6, channel)]), int(self.values[(7, channel)])
                )
            elif param.id in (8, 9, 10):
                ch.pid.gains = self._gains(channel)
                self._configure_hardware(channel)
            elif param.id == 3:
                self._write_hardware_reference(channel)

    # --- the control loop -----------------------------------------------------------------

    def mode(self, code: int) -> int:
        return self.channels[code].mode

    def _current_reference(self, code: int) -> float:
        """The current (A) a torque reference (N·m) asks for."""
        return self.channels[code].reference / float(self.values[(3, code)])

    def _configure_hardware(self, code: int) -> None:
        hardware = self.channels[code].hardware
        if hardware is None:
            return
        limit = int(self.values[(5, code)])
        if self.mode(code) == CURRENT_HW:
            hardware.configure(LoopInput.CURRENT,
                               PidGains(HW_CURRENT_KP, _ELECTRICAL_TAU, 0.0), limit)
        else:
            hardware.configure(LoopInput.SPEED, self._gains(code), limit)
        self._write_hardware_reference(code)

    def _write_hardware_reference(self, code: int) -> None:
        ch = self.channels[code]
        if ch.hardware is not None:
            ch.hardware.write_reference(self._current_reference(code)
                                        if self.mode(code) == CURRENT_HW else ch.reference)

    def _change_controller(self, code: int) -> None:
        """A new controller for the channel: from rest, at reference 0, also while enabled."""
        ch = self.channels[code]
        ch.reference = 0.0
        ch.pid.reset()
        ch.current_pid.reset()
        if ch.hardware is None:
            return
        ch.hardware.stop()
        self._configure_hardware(code)
        if self._enabled and self.mode(code) in HARDWARE_MODES:
            ch.hardware.start(self.board.now)

    def _on_enable(self, change: EnableChange) -> None:
        self._enabled = change.enabled
        for code, ch in self.channels.items():
            if change.enabled:
                if ch.hardware is not None and self.mode(code) in HARDWARE_MODES:
                    ch.hardware.start(change.cycle)
                continue
            if ch.hardware is not None:
                ch.hardware.stop()
            ch.pid.reset()
            ch.current_pid.reset()
            ch.reference = 0.0
            self._write_hardware_reference(code)
            self.board.channels[code].pwm.write_duty(0, change.cycle)

    @property
    def quiescent(self) -> bool:
        """A timer tick now would change nothing observable: disabled, no telemetry, no
        hardware loop, controllers reset, PWM at 0, readings settled, wheels exactly at
        rest. The tick then only counts itself, and a paced board need not wake for it."""
        if self._enabled or self.telemetry_on:
            return False
        board = self.board
        for code, ch in self.channels.items():
            io = board.channels[code]
            if (io.pwm.duty_register or not ch.pid.at_rest or not ch.current_pid.at_rest
                    or (ch.hardware is not None and ch.hardware.running)
                    or not io.encoder.settled or ch.speed or ch.current
                    or ch.position != io.encoder.position):
                return False
        motors = board.peripherals.get("motors")
        return motors is None or bool(getattr(motors, "at_rest", False))

    def skippable_event(self) -> EventHandle | None:
        """The next timer interrupt, when it will change nothing (see :attr:`quiescent`)."""
        if not self.skip_quiescent_ticks or self._enabled or not self.quiescent:
            return None
        return self.board.timer.handle

    def _on_tick(self, cycle: int) -> None:
        self.last_tick = cycle
        if self._frames.due(cycle):
            self._frames.book(cycle, self.board.timer.period_cycles)
        if self.skip_quiescent_ticks and not self._enabled and self.quiescent:
            self._timing.periods += 1  # what a full tick would do, no more
            return
        board = self._board
        assert board is not None
        board.settle(cycle)
        dt = board.timer.period_cycles / CLOCK_HZ
        enabled = self._enabled
        telemetry = self.telemetry_on
        io_channels = board.channels
        samples = []
        for code, ch in self.channels.items():
            io = io_channels[code]
            encoder = io.encoder
            pwm = io.pwm
            ch.speed = speed = encoder.firmware_reader.sample(cycle)
            ch.position = encoder.position
            ch.current = io.current_a
            mode = ch.mode
            if not enabled:
                ch.pid.reset()
                ch.current_pid.reset()
                pwm.write_duty(0, cycle)
                saturated = False
            elif mode == SPEED_SW:
                pid = ch.pid
                pwm.write_duty(pid.update(ch.reference, speed, dt), cycle)
                saturated = pid.saturated
            elif mode == CURRENT_SW:
                pid = ch.current_pid
                # Ti no shorter than the period: the loop stays stable at any timer period.
                if pid.gains.ti != max(_ELECTRICAL_TAU, dt):
                    pid.gains = PidGains(SW_CURRENT_KP, max(_ELECTRICAL_TAU, dt), 0.0)
                pwm.write_duty(pid.update(self._current_reference(code), ch.current, dt),
                               cycle)
                saturated = pid.saturated
            else:  # the FPGA module runs the loop; the software only reports
                assert ch.hardware is not None
                saturated = ch.hardware.saturated
            if telemetry:
                # The channel's part of the TM; no later step of this tick touches it.
                flags = _ENABLE if pwm.global_enable else 0
                if encoder.end_stop:
                    flags |= _END_STOP
                if saturated:
                    flags |= _SATURATED
                # Floats are rounded to float32 when the message is packed. Built with the
                # C constructor: a named tuple's own __new__ is a Python call, two per tick.
                samples.append(tuple.__new__(ChannelTelemetry, (
                    ch.position, speed, ch.current,
                    pwm.duty_register if pwm.global_enable else 0, ch.reference, flags)))
        self._timing.periods += 1
        if telemetry:
            content = encode_telemetry(self._counter.take(),
                                       ((cycle - self._powered_at) // _CYCLES_PER_US)
                                       & 0xFFFF_FFFF, *samples)
            if self.wire_crc.on:
                content = append_crc(content)
            if self.tx.send(content, cycle):
                self.stats.telemetry_sent += 1
            else:
                self.stats.telemetry_dropped += 1
                self._timing.record_miss(cycle, None)


def _channels_of(param: Param) -> tuple[int, ...]:
    return (BOARD,) if param.scope is Scope.BOARD else (CHANNEL_A, CHANNEL_B)


def _stored(param: Param, value: int | float) -> int | float:
    """As the firmware keeps it: int32 or float32."""
    return int(value) if param.type is ParamType.INT else float32(float(value))


def attach_firmware(board: Board, settings: dict[str, Any] | None = None, *,
                    wire_crc: bool = True, identity: bool = True,
                    declarations: int | None = None) -> Firmware:
    firmware = Firmware(settings, wire_crc=wire_crc, identity=identity,
                        declarations=declarations)
    board.add_peripheral("firmware", firmware)
    return firmware
