"""``TM`` fields against the board's registers at the cycle the sample was taken: t_us, the
encoder position register, the applied PWM duty, the enable, the end-stop input and the
controller's saturation (SPEC §4 TM, §6)."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import pytest

from fpgaemu.motor import MAX_DUTY
from fpgalink import Telemetry
from fpgalink.protocol import ParamAck
from fpgalink.protocol.catalogue import ChannelTelemetry
from fpgalink.protocol.params import float32
from tests.support.emulated import MS, Cable

# Every test runs against the Python firmware model and the C core (tests/support/firmwares.py).
pytestmark = pytest.mark.usefixtures("each_firmware")


@dataclass(frozen=True)
class Registers:
    position: int
    pwm: int
    enable: bool
    end_stop: bool
    saturated: bool
    reference: float
    plant_speed: float
    plant_angle: float


def snapshot(host: Cable, code: int) -> Registers:
    ch, io = host.firmware.channels[code], host.io(code)
    return Registers(
        io.encoder.position, io.pwm.applied_duty, host.board.global_enable, io.encoder.end_stop,
        ch.pid.saturated, ch.reference, host.wheel(code).speed_dps, host.wheel(code).angle_deg,
    )


def record_ticks(host: Cable, ticks: int,
                 actions: dict[int, list[str]]) -> dict[int, tuple[Registers, Registers]]:
    """Step tick by tick (each run stops at a timer tick's cycle, after it ran) and keep the
    registers there. ``actions[k]`` happen just after tick ``k``."""
    period = host.timer.period_cycles
    first = host.board.now // period + 1
    seen: dict[int, tuple[Registers, Registers]] = {}
    for k in range(first, first + ticks):
        cycle = k * period
        host.board.run_until(cycle)
        host.drain()
        assert host.timer.next_tick == cycle + period  # the tick at `cycle` ran
        seen[cycle] = (snapshot(host, 1), snapshot(host, 2))
        for action in actions.get(k - first, []):
            if action == "RE":
                host.enable()
            elif action == "RD":
                host.disable()
            elif action == "RV":
                host.references(85.0, -20.0)
            elif action == "endstop A":
                host.io(1).encoder.end_stop = True
            elif action == "endstop B":
                host.io(2).encoder.end_stop = True
            elif action == "release A":
                host.io(1).encoder.end_stop = False
    host.run(0.002, step_ms=1)
    return seen


def check_channel(tm: ChannelTelemetry, reg: Registers) -> None:
    assert tm.position == reg.position
    assert tm.pwm == reg.pwm
    assert bool(tm.flags & 1) == reg.enable
    assert bool(tm.flags & 2) == reg.end_stop
    assert bool(tm.flags & 4) == reg.saturated
    assert tm.flags & ~7 == 0
    assert tm.reference == float32(reg.reference)
    if not reg.enable:
        assert tm.pwm == 0


@pytest.fixture
def streaming() -> Cable:
    host = Cable.make()
    assert isinstance(host.set(2, 0, 1, 1), ParamAck)
    return host


def test_tm_fields_are_the_registers_at_the_sample_cycle(streaming: Cable) -> None:
    host = streaming
    actions = {0: ["RE"], 5: ["RV"], 100: ["RE"], 150: ["endstop A"], 200: ["RE"],
               220: ["release A", "endstop B"], 260: ["RD"], 300: ["RE"], 302: ["RV"],
               400: ["RE"]}
    mark = len(host.telemetry)
    seen = record_ticks(host, 450, actions)
    stream = [tm for tm in host.telemetry[mark:] if tm.t_us * 100 in seen]
    assert len(stream) == len(seen) == 450
    by_time = {tm.t_us: tm for tm in stream}
    for cycle, (reg_a, reg_b) in seen.items():
        tm = by_time[cycle // 100]
        assert tm.t_us == cycle // 100
        check_channel(tm.a, reg_a)
        check_channel(tm.b, reg_b)
    # The run covered what it set out to: driven, saturated, end-stops, disabled.
    assert any(tm.a.saturated for tm in stream) and any(not tm.a.saturated for tm in stream)
    assert any(tm.a.end_stop for tm in stream) and any(tm.b.end_stop for tm in stream)
    assert any(not tm.a.enabled for tm in stream[1:]) and any(tm.a.enabled for tm in stream)
    assert max(tm.a.pwm for tm in stream) == MAX_DUTY
    assert min(tm.b.pwm for tm in stream) < 0 and min(tm.b.position for tm in stream) < -10


def test_tm_current_is_the_motor_current_over_the_period_just_ended(streaming: Cable) -> None:
    # The winding: L·di/dt = V·duty − k_e·ω − R·i over each period, with the duty held since
    # the last tick and the wheel's mean speed over the period (its angle change).
    host = streaming
    seen = record_ticks(host, 300, {0: ["RE"], 1: ["RV"], 100: ["RE"], 200: ["RE"]})
    by_time = {tm.t_us: tm for tm in host.telemetry}
    motor = host.wheel(1).motor
    period_s = host.timer.period_cycles / 100e6
    decay = math.exp(-period_s * motor.resistance_ohm / motor.inductance_h)
    cycles = sorted(seen)
    checked = 0
    for previous, cycle in itertools.pairwise(cycles):
        duty = seen[previous][0].pwm  # held since the last tick
        mean_speed = (seen[cycle][0].plant_angle - seen[previous][0].plant_angle) / period_s
        omega_motor = mean_speed * math.pi / 180 * 70.0
        steady = (motor.supply_v * duty / MAX_DUTY - motor.ke_v_s_per_rad * omega_motor)
        steady /= motor.resistance_ohm
        before = by_time[previous // 100].a.current
        expected = steady + (before - steady) * decay
        assert by_time[cycle // 100].a.current == pytest.approx(expected, rel=1e-5, abs=1e-5)
        checked += 1
    assert checked == 299
    assert max(tm.a.current for tm in host.telemetry) > 15.0  # the saturated start


def test_t_us_is_the_tick_cycle_over_100_at_every_period(streaming: Cable) -> None:
    host = streaming
    assert isinstance(host.set(1, 0, 1, 3), ParamAck)
    since = host.board.now
    host.run(0.3)
    times = [tm.t_us for tm in host.telemetry_since(since)]
    assert len(times) >= 99
    assert all(b - a == 3000 for a, b in itertools.pairwise(times))
    # every TM is dated by a tick, and ticks of a 3 ms timer started at a 1 ms tick
    assert all(t % 1000 == 0 for t in times)


def test_tm_is_sent_whether_enabled_or_not_and_flags_follow_the_enable(streaming: Cable) -> None:
    host = streaming
    host.run(0.05)
    assert host.telemetry and all(not tm.a.enabled and not tm.b.enabled
                                  for tm in host.telemetry)
    stop = host.enable()
    host.run(0.05)
    after: list[Telemetry] = host.telemetry_since(stop + MS)
    assert after and all(tm.a.enabled and tm.b.enabled for tm in after)
