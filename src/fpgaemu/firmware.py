"""The MicroBlaze software (seed §3.2–3.3), written against the board's registers only: the
AXI port to the UART logic, the timer, and each channel's PWM, encoder and current sensor.

* RX interrupt: read the frame from the RX block RAM, acknowledge the half, handle it:
  ``PS`` (validate, apply, recompute, echo ``PA`` or answer ``PN``), ``PG`` (``PA``),
  ``RV`` (references). Malformed and unknown messages are counted and ignored.
* Timer interrupt every TsTimerPeriod ms: sample encoders and current sensors, run the
  controllers, write the PWM registers, and send ``TM`` while GetDataPeriodical = 1.
* ``E`` every 300 ms, enabled or not.
* ``global_enable`` falling (``RD`` or watchdog): integrators reset, references cleared.

Controller modes (parameter 4): 0 (software speed PID) and 1 (hardware speed PID: the same
control law, computed by the FPGA module at the timer tick) are modelled; 2 and 3 (current
PID) are refused with ``PN`` 3, since current control is not modelled.

Power-up values come from the parameter table's ``default`` column.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

from fpgaemu.axi import TxQueue
from fpgaemu.board import Board
from fpgaemu.pid import PidGains, SpeedPid
from fpgaemu.timeline import CLOCK_HZ, ms, us
from fpgaemu.timing import TimingReport
from fpgaemu.uartcommand import EnableChange, RxInterrupt
from fpgaemu.uartsend import TxDone
from fpgalink.protocol import (
    PARAMETERS,
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
    Telemetry,
    TelemetryFlags,
    encode_message,
    float32,
    parse_content,
    resolve,
)
from fpgalink.protocol.params import BOARD, CHANNEL_A, CHANNEL_B

__all__ = ["Firmware", "FirmwareStats", "attach_firmware"]

ALIVE_PERIOD_CYCLES = ms(300)
#: controller modes the emulated firmware runs
SUPPORTED_CONTROLLERS = (0, 1)


class Channel:
    """The software's state for one motor channel: its controller, reference and the
    latest samples of its inputs."""

    def __init__(self, gains: PidGains) -> None:
        self.pid = SpeedPid(gains)
        self.reference = 0.0
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


class Firmware:
    def __init__(self, settings: dict[str, Any] | None = None) -> None:
        self.values: dict[tuple[int, int], int | float] = {}
        for param in PARAMETERS:
            for channel in _channels_of(param):
                self.values[(param.id, channel)] = _stored(param, param.default)
        self.channels = {code: Channel(self._gains(code)) for code in (CHANNEL_A, CHANNEL_B)}
        self.stats = FirmwareStats()
        self.timing = TimingReport()
        self.host_counter = CounterTracker()
        self._counter = SendCounter()
        self._pending_settings = dict(settings or {})
        self._in_flight: deque[tuple[str, int]] = deque()
        self._board: Board | None = None
        self._enabled = False

    def _gains(self, code: int) -> PidGains:
        values = self.values
        return PidGains(float(values[(8, code)]), float(values[(9, code)]),
                        float(values[(10, code)]))

    @property
    def board(self) -> Board:
        assert self._board is not None, "the firmware is not attached to a board"
        return self._board

    # --- wiring ---------------------------------------------------------------------------

    def attach(self, board: Board) -> None:
        self._board = board
        axi = board.axi
        axi.on_rx_interrupt(self._on_rx)
        axi.on_global_enable(self._on_enable)
        axi.on_tx_done(self._on_tx_done)
        self.tx = TxQueue(axi, depth=8)
        now = board.now
        self.timing.started_cycle = now
        for param in PARAMETERS:
            for channel in _channels_of(param):
                self._apply(param, channel, self.values[(param.id, channel)])
        for name, value in self._pending_settings.items():
            param, channel = resolve(name)
            error = self._check(param, channel, int(param.type), value)
            if error is not None:
                raise ValueError(f"initial {name} = {value!r}: {NackReason(error).text}")
            self._apply(param, channel, _stored(param, value))
        board.timer.on_interrupt(self._on_tick)
        board.timer.start(now)
        board.schedule(now + ALIVE_PERIOD_CYCLES, self._on_alive)

    def budget_report(self) -> dict[str, Any]:
        """SPEC §7 from this run (see :meth:`fpgaemu.timing.TimingReport.summary`)."""
        return self.timing.summary(self.board)

    def channel(self, code: int) -> Channel:
        return self.channels[code]

    def value(self, name: str, channel: int | str | None = None) -> int | float:
        param, code = resolve(name, channel)
        return self.values[(param.id, code)]

    # --- sending --------------------------------------------------------------------------

    def _send(self, message: Any, kind: str, tick: int = 0) -> bool:
        content = b"E" if kind == "E" else encode_message(message, self._counter.take())
        if self.tx.send(content):
            self._in_flight.append((kind, tick))
            return True
        return False

    def _on_tx_done(self, done: TxDone) -> None:
        self.timing.tx_wire_bytes += done.wire_bytes
        if not self._in_flight:
            return
        kind, tick = self._in_flight.popleft()
        if kind == "TM":
            deadline = tick + self.board.timer.period_cycles
            self.timing.record_slack(tick, done.cycle, deadline - done.cycle)

    def _on_alive(self, cycle: int) -> None:
        if self._send(None, "E"):
            self.stats.alive_sent += 1
        assert self._board is not None
        self._board.schedule(cycle + ALIVE_PERIOD_CYCLES, self._on_alive)

    # --- receiving ------------------------------------------------------------------------

    def _on_rx(self, irq: RxInterrupt) -> None:
        assert self._board is not None
        axi = self._board.axi
        content = axi.read_rx(irq.start_address, irq.length)
        axi.ack_rx(irq.start_address)
        message = parse_content(content)
        self.stats.messages += 1
        counter = getattr(message, "counter", None)
        if counter is not None:
            self.host_counter.observe(counter)
        if isinstance(message, ParamSet):
            self.stats.param_sets += 1
            self._handle_set(message)
        elif isinstance(message, ParamGet):
            self.stats.param_gets += 1
            self._handle_get(message)
        elif isinstance(message, References):
            # Only the next timer tick reads the references, so the wheels need not be
            # brought up to this cycle. A non-finite reference is refused whole, as a
            # malformed message is: nothing a broken host sends may reach a controller.
            if math.isfinite(message.ref_a) and math.isfinite(message.ref_b):
                self.stats.references += 1
                self.channels[CHANNEL_A].reference = message.ref_a
                self.channels[CHANNEL_B].reference = message.ref_b
            else:
                self.stats.invalid_references += 1
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
        if isinstance(value, float) and not math.isfinite(value):
            return NackReason.OUT_OF_RANGE
        if not param.in_range(value):
            return NackReason.OUT_OF_RANGE
        if param.id == 4 and value not in SUPPORTED_CONTROLLERS:
            return NackReason.OUT_OF_RANGE
        return None

    def _handle_set(self, message: ParamSet) -> None:
        param = _BY_ID.get(message.param_id)
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
        param = _BY_ID.get(message.param_id)
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
        if self._board is None:
            return  # applied to the hardware at attach
        if param.id == 1:
            self.board.timer.set_period_ms(int(value))
        elif param.scope is Scope.CHANNEL:
            ch = self.channels[channel]
            if param.id == 5:
                ch.pid.limit = int(value)
            elif param.id in (6, 7):
                board = self.board
                board.settle(board.now)  # the count restarts from the wheel's angle now
                board.channels[channel].encoder.configure(
                    int(self.values[(6, channel)]), int(self.values[(7, channel)])
                )
            elif param.id in (8, 9, 10):
                ch.pid.gains = self._gains(channel)

    # --- the control loop -----------------------------------------------------------------

    def _on_enable(self, change: EnableChange) -> None:
        self._enabled = change.enabled
        if not change.enabled:
            for code, ch in self.channels.items():
                ch.pid.reset()
                ch.reference = 0.0
                self.board.channels[code].pwm.write_duty(0, change.cycle)

    def _on_tick(self, cycle: int) -> None:
        board = self.board
        board.settle(cycle)
        dt = board.timer.period_cycles / CLOCK_HZ
        saturated = {}
        for code, ch in self.channels.items():
            io = board.channels[code]
            ch.speed = io.encoder.sample_speed(cycle)
            ch.position = io.encoder.position
            ch.current = io.current_a
            if self._enabled and self.values[(4, code)] in SUPPORTED_CONTROLLERS:
                io.pwm.write_duty(ch.pid.update(ch.reference, ch.speed, dt), cycle)
            else:
                ch.pid.reset()
                io.pwm.write_duty(0, cycle)
            saturated[code] = ch.pid.saturated
        self.timing.periods += 1
        if self.values[(2, BOARD)] == 1:
            sample = Telemetry(
                (cycle // us(1)) & 0xFFFF_FFFF,
                self._channel_sample(CHANNEL_A, saturated[CHANNEL_A]),
                self._channel_sample(CHANNEL_B, saturated[CHANNEL_B]),
            )
            if self._send(sample, "TM", cycle):
                self.stats.telemetry_sent += 1
            else:
                self.stats.telemetry_dropped += 1
                self.timing.record_miss(cycle, None)

    def _channel_sample(self, code: int, saturated: bool) -> ChannelTelemetry:
        ch = self.channels[code]
        io = self.board.channels[code]
        flags = 0
        if io.pwm.global_enable:
            flags |= TelemetryFlags.ENABLE
        if io.encoder.end_stop:
            flags |= TelemetryFlags.END_STOP
        if saturated:
            flags |= TelemetryFlags.SATURATED
        # Floats are rounded to float32 when the message is packed.
        return ChannelTelemetry(
            ch.position, ch.speed, ch.current, io.pwm.applied_duty, ch.reference, flags,
        )


_BY_ID = {p.id: p for p in PARAMETERS}


def _channels_of(param: Param) -> tuple[int, ...]:
    return (BOARD,) if param.scope is Scope.BOARD else (CHANNEL_A, CHANNEL_B)


def _stored(param: Param, value: int | float) -> int | float:
    """As the firmware keeps it: int32 or float32."""
    return int(value) if param.type is ParamType.INT else float32(float(value))


def attach_firmware(board: Board, settings: dict[str, Any] | None = None) -> Firmware:
    firmware = Firmware(settings)
    board.add_peripheral("firmware", firmware)
    return firmware
