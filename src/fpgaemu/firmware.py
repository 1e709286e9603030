"""The MicroBlaze software (seed §3.2–3.3), written against the AXI port only.

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

The motors live here too, as the plant the PWM drives (``WheelPlant``), advanced to every
cycle where its input changes (timer ticks, enable edges) and at least every millisecond.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any

from fpgaemu.axi import TxQueue
from fpgaemu.board import Board
from fpgaemu.encoder import QuadratureEncoder
from fpgaemu.pid import DEFAULT_GAINS, PidGains, SpeedPid
from fpgaemu.plant import WheelPlant
from fpgaemu.pwm import Pwm
from fpgaemu.timeline import CLOCK_HZ
from fpgaemu.timer import Timer
from fpgaemu.uartcommand import EnableChange, RxInterrupt
from fpgaemu.uartsend import TxDone
from fpgalink._counter import CounterTracker, SendCounter
from fpgalink._messages import Malformed
from fpgalink.catalogue import (
    ChannelTelemetry,
    NackReason,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    References,
    Telemetry,
    TelemetryFlags,
    encode_message,
    parse_content,
)
from fpgalink.params import (
    BOARD,
    CHANNEL_A,
    CHANNEL_B,
    PARAMETERS,
    Param,
    ParamType,
    Scope,
    float32,
    resolve,
)

__all__ = ["DEFAULTS", "Firmware", "FirmwareStats", "TimingReport", "attach_firmware"]

ALIVE_PERIOD_CYCLES = 300 * CLOCK_HZ // 1000
#: The plant is advanced at least this often, so encoder edges follow the wheel closely.
PLANT_STEP_CYCLES = CLOCK_HZ // 1000
#: controller modes the emulated firmware runs
SUPPORTED_CONTROLLERS = (0, 1)

#: Power-up values, chosen so the board works out of the box (docs/emulator.md).
DEFAULTS: dict[str, int | float] = {
    "TsTimerPeriod": 1,
    "GetDataPeriodical": 0,
    "TorqueCoef": 0.2,
    "ActiveController": 0,
    "MaxControlSignal": 32760,
    "IncSenzRes": 500,
    "IncSenzCountDirection": 1,
    "Kp_Wheel_Pid": DEFAULT_GAINS.kp,
    "Ti_Wheel_Pid": DEFAULT_GAINS.ti,
    "Td_Wheel_Pid": DEFAULT_GAINS.td,
}


class Channel:
    """One motor channel: its PWM stage, encoder, plant and controller."""

    def __init__(self, gear: str) -> None:
        self.pwm = Pwm()
        self.encoder = QuadratureEncoder()
        self.plant = WheelPlant(gear)
        self.pid = SpeedPid()
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
    telemetry_sent: int = 0
    telemetry_dropped: int = 0  #: the TX queue was full
    alive_sent: int = 0


#: Missed periods listed individually (later ones are only counted), so a long run under
#: overload keeps bounded memory.
MISSED_LISTED = 10_000


@dataclass(slots=True)
class TimingReport:
    """How the board's output fitted its periods (SPEC §7). Slack is kept as a histogram of
    exact values (a handful of distinct values in practice), so memory stays flat however
    long the board runs."""

    periods: int = 0
    tm_finished: int = 0
    slack_histogram: Counter[int] = field(default_factory=Counter)
    #: (tick cycle, cycle the TM's last byte ended or None if it was never sent), first
    #: ``MISSED_LISTED`` of them
    missed: list[tuple[int, int | None]] = field(default_factory=list)
    missed_count: int = 0
    tx_wire_bytes: int = 0
    started_cycle: int = 0

    def record_slack(self, tick: int, done: int, slack: int) -> None:
        self.tm_finished += 1
        self.slack_histogram[slack] += 1
        if slack < 0:
            self.record_miss(tick, done)

    def record_miss(self, tick: int, done: int | None) -> None:
        self.missed_count += 1
        if len(self.missed) < MISSED_LISTED:
            self.missed.append((tick, done))

    @property
    def median_slack(self) -> float | None:
        if not self.tm_finished:
            return None
        values = sorted(self.slack_histogram.items())
        middle = (self.tm_finished - 1) / 2
        low = high = None
        seen = 0
        for value, count in values:
            if low is None and seen + count > int(middle):
                low = value
            if seen + count > math.ceil(middle):
                high = value
                break
            seen += count
        assert low is not None and high is not None
        return (low + high) / 2

    @property
    def worst_slack(self) -> int | None:
        return min(self.slack_histogram) if self.slack_histogram else None


class Firmware:
    def __init__(self, settings: dict[str, Any] | None = None, gear: str = "high") -> None:
        self.channels = {CHANNEL_A: Channel(gear), CHANNEL_B: Channel(gear)}
        self.values: dict[tuple[int, int], int | float] = {}
        for param in PARAMETERS:
            for channel in _channels_of(param):
                self.values[(param.id, channel)] = _stored(param, DEFAULTS[param.name])
        self.timer = Timer(int(self.values[(1, BOARD)]))
        self.stats = FirmwareStats()
        self.timing = TimingReport()
        self.host_counter = CounterTracker()
        self._counter = SendCounter()
        self._pending_settings = dict(settings or {})
        self._in_flight: deque[tuple[str, int]] = deque()
        self._board: Board | None = None
        self._plant_cycle = 0
        self._enabled = False
        self._next_alive = 0

    # --- wiring ---------------------------------------------------------------------------

    def attach(self, board: Board) -> None:
        self._board = board
        axi = board.axi
        axi.on_rx_interrupt(self._on_rx)
        axi.on_global_enable(self._on_enable)
        axi.on_tx_done(self._on_tx_done)
        self.tx = TxQueue(axi, depth=8)
        now = board.now
        self._plant_cycle = now
        self.timing.started_cycle = now
        for name, value in self._pending_settings.items():
            param, channel = resolve(name)
            error = self._check(param, channel, int(param.type), value)
            if error is not None:
                raise ValueError(f"initial {name} = {value!r}: {NackReason(error).text}")
            self._apply(param, channel, _stored(param, value))
        board.schedule(self.timer.start(now), self._on_tick)
        board.schedule(now + ALIVE_PERIOD_CYCLES, self._on_alive)

    def budget_report(self) -> dict[str, Any]:
        """SPEC §7 from this run: line utilisation per direction since power-up, slack per
        period (cycles from a TM's last stop bit to the next tick) and the missed periods."""
        assert self._board is not None
        board = self._board
        elapsed = board.now - self.timing.started_cycle
        capacity = elapsed / board.cycles_per_byte if elapsed > 0 else 0.0
        timing = self.timing
        return {
            "periods": timing.periods,
            "board_to_host_utilisation": timing.tx_wire_bytes / capacity if capacity else 0.0,
            "host_to_board_utilisation": (
                board.uartread.stats.bytes_received / capacity if capacity else 0.0
            ),
            "median_slack_cycles": timing.median_slack,
            "worst_slack_cycles": timing.worst_slack,
            "missed_periods": timing.missed_count,
            "missed": list(timing.missed),
        }

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
            deadline = tick + self.timer.period_cycles
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
            # brought up to this cycle.
            self.stats.references += 1
            self.channels[CHANNEL_A].reference = message.ref_a
            self.channels[CHANNEL_B].reference = message.ref_b
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
        if param.id == 1:
            self.timer.set_period_ms(int(value))
        elif param.scope is Scope.CHANNEL:
            ch = self.channels[channel]
            if param.id == 5:
                ch.pid.limit = int(value)
            elif param.id in (6, 7):
                self._advance_plants(self._board.now if self._board else 0)
                ch.encoder.configure(
                    int(self.values[(6, channel)]), int(self.values[(7, channel)]),
                    ch.plant.angle_deg,
                )
            elif param.id in (8, 9, 10):
                ch.pid.gains = PidGains(
                    float(self.values[(8, channel)]),
                    float(self.values[(9, channel)]),
                    float(self.values[(10, channel)]),
                )

    # --- the control loop -----------------------------------------------------------------

    def _advance_plants(self, cycle: int) -> None:
        start = self._plant_cycle
        if cycle <= start:
            return
        for ch in self.channels.values():
            ch.plant.duty = ch.pwm.applied_duty
            c0 = start
            while c0 < cycle:
                c1 = min(cycle, c0 + PLANT_STEP_CYCLES)
                angle0, _ = ch.plant.advance((c1 - c0) / CLOCK_HZ)
                ch.encoder.follow(c0, angle0, c1, ch.plant.angle_deg)
                c0 = c1
        self._plant_cycle = cycle

    def _on_enable(self, change: EnableChange) -> None:
        self._advance_plants(change.cycle)
        self._enabled = change.enabled
        for ch in self.channels.values():
            ch.pwm.set_global_enable(change.enabled)
            if not change.enabled:
                ch.pid.reset()
                ch.reference = 0.0
                ch.pwm.write_duty(0)

    def _on_tick(self, cycle: int) -> None:
        assert self._board is not None
        self._advance_plants(cycle)
        dt = self.timer.period_cycles / CLOCK_HZ
        mode_ok = True
        saturated = {}
        for code, ch in self.channels.items():
            ch.speed = ch.encoder.sample_speed(cycle)
            ch.position = ch.encoder.position
            ch.current = ch.plant.current_a
            mode_ok = self.values[(4, code)] in SUPPORTED_CONTROLLERS
            if self._enabled and mode_ok:
                ch.pwm.write_duty(ch.pid.update(ch.reference, ch.speed, dt))
            else:
                ch.pid.reset()
                ch.pwm.write_duty(0)
            saturated[code] = ch.pid.saturated
            ch.plant.duty = ch.pwm.applied_duty
        next_tick = self.timer.tick(cycle)
        self.timing.periods += 1
        if self.values[(2, BOARD)] == 1:
            sample = Telemetry(
                (cycle // (CLOCK_HZ // 1_000_000)) & 0xFFFF_FFFF,
                self._channel_sample(CHANNEL_A, saturated[CHANNEL_A]),
                self._channel_sample(CHANNEL_B, saturated[CHANNEL_B]),
            )
            if self._send(sample, "TM", cycle):
                self.stats.telemetry_sent += 1
            else:
                self.stats.telemetry_dropped += 1
                self.timing.record_miss(cycle, None)
        self._board.schedule(next_tick, self._on_tick)

    def _channel_sample(self, code: int, saturated: bool) -> ChannelTelemetry:
        ch = self.channels[code]
        flags = 0
        if ch.pwm.global_enable:
            flags |= TelemetryFlags.ENABLE
        if ch.encoder.end_stop:
            flags |= TelemetryFlags.END_STOP
        if saturated:
            flags |= TelemetryFlags.SATURATED
        # Floats are rounded to float32 when the message is packed.
        return ChannelTelemetry(
            ch.position, ch.speed, ch.current, ch.pwm.applied_duty, ch.reference, flags,
        )


_BY_ID = {p.id: p for p in PARAMETERS}


def _channels_of(param: Param) -> tuple[int, ...]:
    return (BOARD,) if param.scope is Scope.BOARD else (CHANNEL_A, CHANNEL_B)


def _stored(param: Param, value: int | float) -> int | float:
    """As the firmware keeps it: int32 or float32."""
    return int(value) if param.type is ParamType.INT else float32(float(value))


def attach_firmware(board: Board, settings: dict[str, Any] | None = None) -> Firmware:
    firmware = Firmware(settings, gear=board.config.gear)
    board.add_peripheral("firmware", firmware)
    return firmware
