"""The software speed PID on its own, then closed around the emulated wheel plant.

The acceptance figure of part 2: the software speed PID closed through the emulated
encoder and plant. A 0 → 45 deg/s step at TsTimerPeriod = 1 ms settles within 2 % in under
1.5 s with under 10 % overshoot; 20 ms is still stable. Figures are in docs/emulator_models.md."""

from __future__ import annotations

import math

import pytest

from fpgaemu.motor import GEARS
from fpgaemu.pid import Pid, PidGains
from fpgalink.protocol import float32
from tests.support.plant import DEFAULT_GAINS, step_response

TS = 0.001


def test_proportional_and_integral_action() -> None:
    pid = Pid(PidGains(kp=100.0, ti=0.5, td=0.0))
    first = pid.update(10.0, 0.0, TS)
    assert first == round(100 * 10 + 100 * TS / 0.5 * 10)
    for _ in range(499):
        out = pid.update(10.0, 0.0, TS)
    # After Ti the integral has added one more proportional part.
    assert out == pytest.approx(2 * 100 * 10, abs=2)
    assert not pid.saturated


def test_output_clamp_and_saturated_flag() -> None:
    pid = Pid(PidGains(kp=1000.0, ti=0.2, td=0.0), limit=8000)
    assert pid.update(45.0, 0.0, TS) == 8000 and pid.saturated
    assert pid.update(-45.0, 0.0, TS) == -8000 and pid.saturated
    zero = Pid(PidGains(kp=1000.0, ti=0.2, td=0.0), limit=0)
    assert zero.update(45.0, 0.0, TS) == 0


def test_anti_windup_keeps_the_integrator_out_of_a_long_saturation() -> None:
    pid = Pid(PidGains(kp=500.0, ti=0.2, td=0.0), limit=32760)
    for _ in range(3000):  # 3 s pinned at the limit
        pid.update(200.0, 0.0, TS)
    assert abs(pid.integral) < 32760
    # Once the error reverses, the output leaves the limit at once.
    assert pid.update(0.0, 10.0, TS) < 0


def test_derivative_acts_on_the_measurement_not_the_reference() -> None:
    pid = Pid(PidGains(kp=100.0, ti=1e9, td=0.1))
    pid.update(0.0, 0.0, TS)
    step = pid.update(50.0, 0.0, TS)  # reference step: no derivative kick
    assert step == pytest.approx(100 * 50, abs=1)
    moved = pid.update(50.0, 1.0, TS)  # the measurement rises: derivative pulls back
    assert moved < 100 * 49


def test_reset_clears_the_state() -> None:
    pid = Pid(PidGains(kp=100.0, ti=0.1, td=0.05))
    for _ in range(100):
        pid.update(30.0, 5.0, TS)
    pid.reset()
    fresh = Pid(PidGains(kp=100.0, ti=0.1, td=0.05))
    assert pid.update(30.0, 5.0, TS) == fresh.update(30.0, 5.0, TS)
    assert pid.integral == fresh.integral and not pid.saturated


def test_changing_gains_does_not_bump_the_output() -> None:
    pid = Pid(PidGains(kp=100.0, ti=0.2, td=0.0))
    for _ in range(300):
        out = pid.update(20.0, 20.0, TS)  # zero error: output is the integral alone
    pid.integral = 5000.0
    before = pid.update(20.0, 20.0, TS)
    pid.gains = PidGains(kp=100.0, ti=2.0, td=0.0)
    assert pid.update(20.0, 20.0, TS) == before
    assert out == 0


HIGH_DC = sum(GEARS["high"][0]) / (1 + sum(GEARS["high"][1]))
COUNTS_PER_SEED_UNIT = abs(HIGH_DC) * 32760 / 90.0  # ≈ 352 PWM counts


def seed_tuning(kp: float, ki: float, kd: float) -> PidGains:
    return PidGains(kp * COUNTS_PER_SEED_UNIT, kp / ki, kd / kp)


@pytest.mark.parametrize("reference", [45.0, -45.0])
def test_default_gains_settle_a_45_dps_step_at_1_ms(reference: float) -> None:
    run = step_response(reference, period_ms=1)
    assert run.overshoot() < 0.10
    assert run.settling_time() < 1.5
    # What the firmware and TM see (the M/T reading) settles too.
    assert run.overshoot(run.measured) < 0.10
    assert run.settling_time(signal=run.measured) < 1.5
    assert run.true_speed[-1] == pytest.approx(reference, rel=0.01)


def test_default_gains_figures_are_what_the_docs_say() -> None:
    run = step_response(45.0, period_ms=1)
    assert run.overshoot() < 0.01
    assert 0.4 < run.settling_time() < 0.7


@pytest.mark.parametrize("period_ms", [5, 10, 20])
def test_slower_timer_periods_stay_stable(period_ms: int) -> None:
    run = step_response(45.0, period_ms=period_ms, duration_s=3.0)
    assert run.overshoot() < 0.10
    assert run.settling_time() < 1.5
    tail = run.true_speed[-round(0.5 / run.period_s):]
    assert max(tail) - min(tail) < 0.02 * 45.0


def test_small_and_large_steps_and_the_duty_limit() -> None:
    small = step_response(5.0)
    assert small.settling_time() < 1.5 and small.overshoot() < 0.10
    # 85 deg/s needs 94 % duty: the output saturates for a while, anti-windup keeps the
    # overshoot small.
    large = step_response(85.0, duration_s=3.0)
    assert max(large.duty) == 32760
    assert large.overshoot() < 0.10 and large.settling_time() < 2.0
    # A clamp below what the reference needs: the wheel tops out where the duty does.
    clamped = step_response(45.0, limit=8190)
    assert max(abs(d) for d in clamped.duty) <= 8190
    assert clamped.true_speed[-1] == pytest.approx(90.0 * 8190 / 32760, rel=0.01)


def test_low_gear_with_the_high_gear_defaults_is_slower_but_stable() -> None:
    run = step_response(20.0, duration_s=4.0, gear="low")
    assert run.overshoot() < 0.10
    assert run.settling_time() < 3.0
    assert run.true_speed[-1] == pytest.approx(20.0, rel=0.02)


def test_seed_tunings_read_literally_do_not_move_the_wheel() -> None:
    # Kp 7.11 PWM counts per deg/s, Ti 23.66 s, Td 0.43 s: about 1 % duty for a 45 deg/s
    # error, and an integral that takes minutes.
    run = step_response(45.0, PidGains(7.11, 23.66, 0.43))
    assert run.true_speed[-1] < 2.0


def test_seed_tunings_converted_track_at_1_ms_and_lose_margin_at_20_ms() -> None:
    gains = seed_tuning(7.11, 23.66, 0.43)
    assert gains.kp == pytest.approx(2502, rel=0.01)
    assert gains.ti == pytest.approx(0.3005, rel=0.001)
    assert gains.td == pytest.approx(0.0605, rel=0.001)
    fast = step_response(45.0, gains, period_ms=1)
    assert fast.overshoot() < 0.10 and fast.settling_time() < 1.5
    slow = step_response(45.0, gains, period_ms=20, duration_s=3.0)
    assert slow.settling_time() > fast.settling_time()


def test_default_gains_are_the_documented_ones() -> None:
    assert PidGains(kp=520.0, ti=float32(0.24), td=0.0) == DEFAULT_GAINS


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_input_outputs_zero_and_never_enters_the_state(bad: float) -> None:
    pid = Pid(PidGains(kp=500.0, ti=0.2, td=0.05))
    for _ in range(50):
        pid.update(30.0, 10.0, TS)
    assert pid.update(bad, 10.0, TS) == 0
    assert pid.update(30.0, bad, TS) == 0
    assert pid.integral == 0.0 and not pid.saturated
    # Back to finite inputs: an ordinary controller from rest, not one latched at its limit.
    fresh = Pid(PidGains(kp=500.0, ti=0.2, td=0.05))
    assert pid.update(0.0, 0.0, TS) == fresh.update(0.0, 0.0, TS) == 0


def test_an_overflowing_controller_drives_nothing_and_restarts_from_rest() -> None:
    # Gains past any parameter's range: proportional and integral +inf, derivative -inf.
    pid = Pid(PidGains(kp=1e308, ti=1e-308, td=1e308))
    assert pid.update(10.0, 0.0, TS) == 32760  # +inf: saturated, as a large error is
    assert pid.saturated
    assert pid.update(10.0, 1.0, TS) == 0  # inf - inf: NaN
    assert pid.at_rest


@pytest.mark.parametrize(("name", "seed"), [("seed-high", (7.11, 23.66, 0.43)),
                                            ("seed-low", (15.96, 51.51, 1.237))])
def test_the_shipped_seed_sets_are_the_conversion(name: str, seed: tuple[float, float, float]
                                                 ) -> None:
    from importlib import resources

    from fpgalink.protocol.paramfile import parse_parameter_file

    text = (resources.files("fpgalink.parameter_sets") / f"{name}.toml").read_text()
    values = {p.full_name(c): v for p, c, v in parse_parameter_file(text, name)}
    expected = seed_tuning(*seed)
    for channel in "AB":
        assert values[f"Kp_Wheel_Pid{channel}"] == pytest.approx(expected.kp, rel=1e-6)
        assert values[f"Ti_Wheel_Pid{channel}"] == pytest.approx(expected.ti, rel=1e-6)
        assert values[f"Td_Wheel_Pid{channel}"] == pytest.approx(expected.td, rel=1e-6)
        assert values[f"ActiveController{channel}"] == 0
