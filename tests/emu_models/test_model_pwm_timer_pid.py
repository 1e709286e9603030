"""PWM stage, timer peripheral and the software speed PID, each on its own."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgaemu.pid import PidGains, SpeedPid
from fpgaemu.pwm import MAX_DUTY, Pwm
from fpgaemu.timer import Timer

# --- PWM -------------------------------------------------------------------------------------


@given(st.integers(-100_000, 100_000), st.booleans())
def test_pwm_clamps_and_gates(duty: int, enabled: bool) -> None:
    pwm = Pwm()
    pwm.set_global_enable(enabled)
    pwm.write_duty(duty)
    assert pwm.duty_register == max(-MAX_DUTY, min(MAX_DUTY, duty))
    assert pwm.applied_duty == (pwm.duty_register if enabled else 0)
    assert pwm.direction == (pwm.applied_duty > 0) - (pwm.applied_duty < 0)


def test_pwm_output_is_low_until_enabled_and_again_after() -> None:
    pwm = Pwm()
    pwm.write_duty(-12000)
    assert pwm.applied_duty == 0 and pwm.direction == 0
    pwm.set_global_enable(True)
    assert pwm.applied_duty == -12000 and pwm.direction == -1
    pwm.set_global_enable(False)
    assert pwm.applied_duty == 0
    assert pwm.duty_register == -12000  # the register keeps what the processor wrote


# --- timer -----------------------------------------------------------------------------------


def test_timer_period_in_cycles() -> None:
    timer = Timer(1)
    assert timer.period_cycles == 100_000
    assert timer.start(5) == 100_005
    assert timer.tick(100_005) == 200_005
    assert timer.ticks == 1
    assert Timer(1000).period_cycles == 100_000_000


def test_new_period_takes_effect_from_the_next_tick() -> None:
    timer = Timer(1)
    pending = timer.start(0)
    timer.set_period_ms(20)
    assert timer.next_tick == pending  # the running count is not cut short
    assert timer.tick(pending) == pending + 2_000_000


@pytest.mark.parametrize("bad", [0, 1001, -1])
def test_timer_refuses_periods_outside_the_parameter_range(bad: int) -> None:
    with pytest.raises(ValueError):
        Timer(bad)
    with pytest.raises(ValueError):
        Timer(1).set_period_ms(bad)


# --- PID -------------------------------------------------------------------------------------

TS = 0.001


def test_proportional_and_integral_action() -> None:
    pid = SpeedPid(PidGains(kp=100.0, ti=0.5, td=0.0))
    first = pid.update(10.0, 0.0, TS)
    assert first == round(100 * 10 + 100 * TS / 0.5 * 10)
    for _ in range(499):
        out = pid.update(10.0, 0.0, TS)
    # After Ti the integral has added one more proportional part.
    assert out == pytest.approx(2 * 100 * 10, abs=2)
    assert not pid.saturated


def test_output_clamp_and_saturated_flag() -> None:
    pid = SpeedPid(PidGains(kp=1000.0, ti=0.2, td=0.0), limit=8000)
    assert pid.update(45.0, 0.0, TS) == 8000 and pid.saturated
    assert pid.update(-45.0, 0.0, TS) == -8000 and pid.saturated
    zero = SpeedPid(limit=0)
    assert zero.update(45.0, 0.0, TS) == 0


def test_anti_windup_keeps_the_integrator_out_of_a_long_saturation() -> None:
    pid = SpeedPid(PidGains(kp=500.0, ti=0.2, td=0.0), limit=32760)
    for _ in range(3000):  # 3 s pinned at the limit
        pid.update(200.0, 0.0, TS)
    assert abs(pid.integral) < 32760
    # Once the error reverses, the output leaves the limit at once.
    assert pid.update(0.0, 10.0, TS) < 0


def test_derivative_acts_on_the_measurement_not_the_reference() -> None:
    pid = SpeedPid(PidGains(kp=100.0, ti=1e9, td=0.1))
    pid.update(0.0, 0.0, TS)
    step = pid.update(50.0, 0.0, TS)  # reference step: no derivative kick
    assert step == pytest.approx(100 * 50, abs=1)
    moved = pid.update(50.0, 1.0, TS)  # the measurement rises: derivative pulls back
    assert moved < 100 * 49


def test_reset_clears_the_state() -> None:
    pid = SpeedPid(PidGains(kp=100.0, ti=0.1, td=0.05))
    for _ in range(100):
        pid.update(30.0, 5.0, TS)
    pid.reset()
    fresh = SpeedPid(PidGains(kp=100.0, ti=0.1, td=0.05))
    assert pid.update(30.0, 5.0, TS) == fresh.update(30.0, 5.0, TS)
    assert pid.integral == fresh.integral and not pid.saturated


def test_changing_gains_does_not_bump_the_output() -> None:
    pid = SpeedPid(PidGains(kp=100.0, ti=0.2, td=0.0))
    for _ in range(300):
        out = pid.update(20.0, 20.0, TS)  # zero error: output is the integral alone
    pid.integral = 5000.0
    before = pid.update(20.0, 20.0, TS)
    pid.gains = PidGains(kp=100.0, ti=2.0, td=0.0)
    assert pid.update(20.0, 20.0, TS) == before
    assert out == 0
