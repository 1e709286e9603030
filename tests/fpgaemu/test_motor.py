"""The wheel plant against the seed's identified models (SPEC §6).

The plant against the seed's identification (SPEC §6): the modal model sampled at Ts =
0.05 s against H(z), full duty, the low gear's ratio, a stalled wheel, a load torque; on its
own and inside the board."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgaemu.motor import (
    GEARS,
    MAX_DUTY,
    WheelPlant,
    continuous_model,
    identified_response,
)
from fpgaemu.timeline import seconds_to_cycles
from fpgalink.protocol import ParamAck
from tests.support.emulated import Cable

HIGH_DC = sum(GEARS["high"][0]) / (1 + sum(GEARS["high"][1]))
LOW_DC = sum(GEARS["low"][0]) / (1 + sum(GEARS["low"][1]))


def run(plant: WheelPlant, duty: int, seconds: float, piece: float = 0.001) -> None:
    plant.duty = duty
    for _ in range(round(seconds / piece)):
        plant.advance(piece)


@pytest.mark.parametrize(("gear", "tolerance"), [("high", 0.001), ("low", 0.01)])
def test_sampled_step_response_matches_the_identified_model(gear: str, tolerance: float) -> None:
    # Sign flipped (the seed's encoder counted backwards) and scaled to deg/s.
    scale = 90.0 / HIGH_DC
    seed = [scale * y for y in identified_response(gear, [0.5] * 60)]
    plant = WheelPlant(gear)
    plant.duty = MAX_DUTY // 2
    ours = []
    for _ in range(60):
        ours.append(plant.speed_dps)
        plant.advance(0.05)
    full = abs(seed[-1])
    assert max(abs(a - b) for a, b in zip(ours, seed, strict=True)) < tolerance * full


def test_continuous_model_poles_and_minimum_phase_zero() -> None:
    high = continuous_model("high")
    assert min(-p.real for p in high.poles) == pytest.approx(1 / 0.2411, rel=1e-3)
    assert all(p.real < 0 for p in high.poles)
    for gear in ("high", "low"):
        assert continuous_model(gear).zero_c > 0  # left half plane: no inverse response


@pytest.mark.parametrize("gear", ["high", "low"])
def test_a_forward_step_never_turns_the_wheel_backwards(gear: str) -> None:
    plant = WheelPlant(gear)
    plant.duty = MAX_DUTY
    for _ in range(500):
        plant.advance(0.0002)
        assert plant.speed_dps >= 0.0 and plant.angle_deg >= 0.0


def test_full_duty_gives_90_dps_in_high_gear_and_the_dc_ratio_in_low() -> None:
    high, low = WheelPlant("high"), WheelPlant("low")
    run(high, MAX_DUTY, 4.0)
    run(low, MAX_DUTY, 4.0)
    assert high.speed_dps == pytest.approx(90.0, rel=1e-3)
    assert low.speed_dps == pytest.approx(90.0 * LOW_DC / HIGH_DC, rel=1e-3)
    assert low.max_speed_dps == pytest.approx(31.38, abs=0.01)
    reverse = WheelPlant()
    run(reverse, -MAX_DUTY, 4.0)
    assert reverse.speed_dps == pytest.approx(-90.0, rel=1e-3)
    assert reverse.angle_deg < 0


def test_dominant_time_constant_is_about_a_quarter_second() -> None:
    plant = WheelPlant()
    plant.duty = MAX_DUTY
    t = 0.0
    while plant.speed_dps < 90.0 * (1 - math.exp(-1)):
        plant.advance(0.001)
        t += 0.001
    assert 0.2 < t < 0.3


@given(st.lists(st.tuples(st.integers(-MAX_DUTY, MAX_DUTY), st.integers(1, 400)),
                min_size=1, max_size=8))
def test_splitting_a_hold_changes_nothing(schedule: list[tuple[int, int]]) -> None:
    # Exact modal stepping: one long step equals many short ones.
    whole, pieces = WheelPlant(), WheelPlant()
    for duty, ms in schedule:
        whole.duty = pieces.duty = duty
        whole.advance(ms / 1000)
        for _ in range(ms):
            pieces.advance(0.001)
    assert pieces.speed_dps == pytest.approx(whole.speed_dps, abs=1e-9)
    assert pieces.angle_deg == pytest.approx(whole.angle_deg, abs=1e-8)


def test_angle_is_the_integral_of_speed() -> None:
    plant = WheelPlant()
    plant.duty = 20000
    integral = 0.0
    dt = 0.0001
    for k in range(15000):
        if k == 6000:
            plant.duty = -5000
        _, speed0 = plant.advance(dt)
        integral += 0.5 * (speed0 + plant.speed_dps) * dt
    assert plant.angle_deg == pytest.approx(integral, abs=1e-4)


def test_advance_returns_the_start_of_the_step() -> None:
    plant = WheelPlant()
    run(plant, 10000, 0.2)
    angle, speed = plant.angle_deg, plant.speed_dps
    assert plant.advance(0.001) == (angle, speed)
    assert plant.advance(0.0) == (plant.angle_deg, plant.speed_dps)


def test_current_follows_the_dc_motor_equation() -> None:
    plant = WheelPlant()
    motor = plant.motor
    plant.duty = MAX_DUTY
    assert plant.current_a == 0.0  # the winding's current cannot jump
    tau = motor.inductance_h / motor.resistance_ohm
    plant.advance(tau)  # one time constant at (almost) rest: 1 − 1/e of the stall current
    stall = motor.supply_v / motor.resistance_ohm
    assert plant.current_a == pytest.approx(stall * (1 - math.exp(-1)), rel=0.01)
    run(plant, MAX_DUTY, 4.0)
    # 90 % of the supply as back-EMF at full speed: 2.4 A of no-load current.
    assert plant.current_a == pytest.approx(0.1 * motor.supply_v / motor.resistance_ohm,
                                            rel=0.01)
    run(plant, 0, 4.0)
    assert abs(plant.current_a) < 0.01


def test_load_torque_slows_the_wheel_and_draws_current() -> None:
    free, loaded = WheelPlant(), WheelPlant()
    loaded.load_torque_nm = 0.25 * loaded.motor.stall_torque_wheel_nm
    run(free, MAX_DUTY, 4.0)
    run(loaded, MAX_DUTY, 4.0)
    assert loaded.speed_dps == pytest.approx(0.75 * free.speed_dps, rel=1e-3)
    assert loaded.current_a > free.current_a
    held = WheelPlant()
    held.load_torque_nm = held.motor.stall_torque_wheel_nm
    run(held, MAX_DUTY, 4.0)
    assert abs(held.speed_dps) < 0.01


def test_a_stalled_wheel_stands_still_and_draws_stall_current() -> None:
    plant = WheelPlant()
    run(plant, MAX_DUTY, 1.0)
    angle = plant.angle_deg
    plant.stall()
    run(plant, MAX_DUTY, 0.5)
    assert plant.speed_dps == 0.0 and plant.angle_deg == angle
    assert plant.current_a == pytest.approx(plant.motor.supply_v / plant.motor.resistance_ohm)
    plant.stall(False)
    run(plant, MAX_DUTY, 0.01)
    assert 0.0 < plant.speed_dps < 10.0  # restarting from rest


def test_unknown_gear_is_refused() -> None:
    with pytest.raises(ValueError, match="gear"):
        WheelPlant("reverse")


TS = 0.05


def dc_gain(gear: str) -> float:
    (b1, b2), (a1, a2, a3) = GEARS[gear]
    return (b1 + b2) / (1 + a1 + a2 + a3)


#: H(z) in the seed's units → deg/s per unit of duty/32760 (sign: physical direction)
SCALE = 90.0 / dc_gain("high")


def sampled(plant: WheelPlant, duties: list[int]) -> list[float]:
    """Speed at k·Ts with duty[j] held over [j·Ts, (j+1)·Ts): what H(z) predicts for out[k]."""
    out = []
    for duty in duties:
        out.append(plant.speed_dps)
        plant.duty = duty
        plant.advance(TS)
    return out


# Fit tolerance of the minimum-phase continuous model (plant.py docstring): 0.03 % (high)
# and 0.8 % (low) of the final value on the step; a little more on arbitrary inputs.
TOLERANCE = {"high": 0.002, "low": 0.012}


@pytest.mark.parametrize("gear", ["high", "low"])
def test_modal_model_reproduces_the_identified_step_sample_for_sample(gear: str) -> None:
    n = 100
    model = sampled(WheelPlant(gear), [MAX_DUTY] * n)
    seed = [SCALE * y for y in identified_response(gear, [1.0] * n)]
    final = abs(seed[-1])
    assert model[0] == seed[0] == 0.0
    for k in range(n):
        assert abs(model[k] - seed[k]) <= TOLERANCE[gear] * final, k


@pytest.mark.parametrize("gear", ["high", "low"])
def test_modal_model_follows_h_of_z_on_a_random_held_input(gear: str) -> None:
    rng = np.random.default_rng(7)
    duties = [int(d) for d in rng.integers(-MAX_DUTY, MAX_DUTY + 1, 200)]
    model = sampled(WheelPlant(gear), duties)
    seed = [SCALE * y for y in identified_response(gear, [d / MAX_DUTY for d in duties])]
    top = WheelPlant(gear).max_speed_dps  # full-duty speed: 90 (high), 31.4 (low) deg/s
    errors = [abs(a - b) for a, b in zip(model, seed, strict=True)]
    # measured: 0.065 % (high), 1.6 % (low) of full speed on white ±100 % duty
    assert max(errors) <= {"high": 0.002, "low": 0.02}[gear] * top
    # and it is the same signal, not merely a small one
    assert np.corrcoef(model, seed)[0, 1] > 0.999


def test_split_steps_give_the_same_wheel() -> None:
    one, many = WheelPlant(), WheelPlant()
    one.duty = many.duty = 20000
    one.advance(TS)
    for _ in range(50):
        many.advance(TS / 50)
    assert many.speed_dps == pytest.approx(one.speed_dps, rel=1e-9)
    assert many.angle_deg == pytest.approx(one.angle_deg, rel=1e-9)


def test_full_duty_gives_90_dps_in_high_gear_and_the_ratio_in_low() -> None:
    high, low = WheelPlant("high"), WheelPlant("low")
    for plant in (high, low):
        plant.duty = MAX_DUTY
        plant.advance(4.0)
    assert high.speed_dps == pytest.approx(90.0, rel=1e-4)
    ratio = dc_gain("low") / dc_gain("high")
    assert ratio == pytest.approx(0.3487, abs=1e-4)
    assert low.speed_dps == pytest.approx(90.0 * ratio, rel=1e-4)
    reverse = WheelPlant("high")
    reverse.duty = -MAX_DUTY
    reverse.advance(4.0)
    assert reverse.speed_dps == pytest.approx(-90.0, rel=1e-4)


@pytest.mark.parametrize(("gear", "top"), [("high", 90.0), ("low", 31.38)])
def test_board_at_full_duty_reports_top_speed_in_tm(gear: str, top: float) -> None:
    # A reference beyond reach saturates the loop at full duty: TM shows the top speed.
    host = Cable.make(gear=gear)
    assert isinstance(host.set(2, 0, 1, 1), ParamAck)
    host.start_enabled()
    host.references(200.0, -200.0)
    host.run(3.0)
    last = host.telemetry[-1]
    assert last.a.pwm == MAX_DUTY and last.b.pwm == -MAX_DUTY
    assert last.a.saturated and last.b.saturated
    assert last.a.speed == pytest.approx(top, rel=0.002)
    assert last.b.speed == pytest.approx(-top, rel=0.002)


def test_stalled_wheel_reads_speed_0_and_draws_the_stall_current() -> None:
    plant = WheelPlant()
    plant.duty = MAX_DUTY
    plant.advance(1.0)
    plant.stall()
    plant.advance(1.0)
    assert plant.speed_dps == 0.0
    stall_current = plant.motor.supply_v / plant.motor.resistance_ohm
    assert plant.current_a == pytest.approx(stall_current)
    assert stall_current == 24.0
    plant.duty = MAX_DUTY // 2
    plant.advance(0.05)  # 50 electrical time constants
    assert plant.current_a == pytest.approx(stall_current * (MAX_DUTY // 2) / MAX_DUTY)


def test_board_with_a_stalled_wheel_winds_up_to_full_duty_and_stall_current() -> None:
    host = Cable.make()
    assert isinstance(host.set(2, 0, 1, 1), ParamAck)
    host.start_enabled()
    host.references(45.0, 45.0)
    host.run(1.0)
    host.wheel(1).stall()
    host.run(2.0)
    last = host.telemetry[-1]
    assert last.a.speed == 0.0  # no edge for over the M/T timeout
    assert last.a.pwm == MAX_DUTY and last.a.saturated
    assert last.a.current == pytest.approx(24.0, rel=1e-6)
    assert last.b.speed == pytest.approx(45.0, rel=0.01)  # the other wheel carries on


@pytest.mark.parametrize("fraction", [0.1, 0.25, 0.5])
def test_load_torque_reduces_speed_in_proportion(fraction: float) -> None:
    plant = WheelPlant()
    plant.duty = MAX_DUTY
    plant.load_torque_nm = fraction * plant.motor.stall_torque_wheel_nm
    plant.advance(4.0)
    assert plant.speed_dps == pytest.approx(90.0 * (1 - fraction), rel=1e-4)


def test_board_loop_rejects_a_load_torque_with_more_duty() -> None:
    host = Cable.make()
    assert isinstance(host.set(2, 0, 1, 1), ParamAck)
    host.start_enabled()
    host.references(45.0, 45.0)
    host.run(1.5)
    duty_free = host.telemetry[-1].a.pwm
    plant = host.wheel(1)
    plant.load_torque_nm = 0.25 * plant.motor.stall_torque_wheel_nm
    mark = len(host.telemetry)
    host.run(2.5)
    dip = min(tm.a.speed for tm in host.telemetry[mark:])
    last = host.telemetry[-1]
    assert dip < 45.0 * 0.95  # the load slows the wheel at first
    assert last.a.speed == pytest.approx(45.0, rel=0.01)  # then the integrator recovers it
    assert last.a.pwm - duty_free == pytest.approx(0.25 * MAX_DUTY, rel=0.02)
    assert last.a.current > host.telemetry[mark - 1].a.current


def test_hall_sensor_noise_is_optional_seeded_and_of_the_asked_size() -> None:
    from fpgaemu import build_board

    def readings(seed: int, noise: float) -> list[float]:
        board = build_board(seed=seed, current_noise_a=noise)
        out = []
        for k in range(1, 2001):
            board.run_until(k * 10_000)
            board.settle(board.now)
            out.append(board.channels[1].current_a)
        return out

    quiet = readings(1, 0.0)
    assert set(quiet) == {0.0}  # at rest, no noise: exactly zero
    noisy = readings(1, 0.05)
    assert noisy == readings(1, 0.05) and noisy != readings(2, 0.05)
    mean = sum(noisy) / len(noisy)
    spread = (sum((x - mean) ** 2 for x in noisy) / len(noisy)) ** 0.5
    assert abs(mean) < 0.01 and spread == pytest.approx(0.05, rel=0.1)


def test_an_unpowered_wheel_comes_to_exact_rest_where_its_decay_would_end() -> None:
    # Static friction's dead band: driven at full duty, then unpowered, the wheel is exactly
    # at rest within a few seconds (without it, minutes, until float underflow), and stands
    # where the identified model's motion ends, to far below one encoder count.
    from fpgaemu.motor import REST_SPEED_DPS

    plant = WheelPlant("high")
    plant.duty = MAX_DUTY
    for _ in range(2000):
        plant.hold(0.001)
    plant.duty = 0
    # Where the same motion would end without the dead band: its limit.
    limit = plant.angle_deg + sum(
        (-(c * x / s)).real for c, x, s in zip(plant._c, plant._x, plant._s, strict=True))
    steps = 0
    while not plant.at_rest:
        plant.hold(0.001)
        steps += 1
        assert steps < 4000, "still not at rest after 4 s unpowered"
    assert steps > 1500  # it coasted down first: the dead band is at creep speed only
    assert plant.speed_dps == 0.0 and plant.current == 0.0
    assert plant.angle_deg == pytest.approx(limit, abs=1e-6)
    assert REST_SPEED_DPS * 72 < 0.1  # one count (0.072°) at the band's edge takes > 70 s


def test_a_wheel_swinging_through_zero_speed_is_not_caught_by_the_dead_band() -> None:
    # The complex pair makes the speed cross zero while the wheel still has motion in it:
    # the dead band judges the motion left (every mode), not the speed of the moment.
    plant = WheelPlant("high")
    plant.duty = -MAX_DUTY
    plant.hold(0.03)
    plant.duty = 0
    crossed = False
    previous = plant.speed_dps
    for _ in range(300):
        plant.hold(0.0001)
        crossed |= (previous < 0) != (plant.speed_dps < 0)
        previous = plant.speed_dps
        if plant.at_rest:
            break
    assert not plant.at_rest
    assert abs(plant.speed_dps) > 1e-3 or crossed


def test_a_board_that_was_driven_becomes_quiescent_again() -> None:
    # The board idles after use as it does fresh: disabled, telemetry off, wheels at rest.
    from tests.support.emulated import Cable

    host = Cable.make()
    assert isinstance(host.set(2, 0, 1, 1), ParamAck)
    host.start_enabled()
    host.references(60.0, -40.0)
    host.run(1.0)
    host.keep_enabled = False
    host.disable()
    assert isinstance(host.set(2, 0, 1, 0), ParamAck)
    firmware: Any = host.board.peripherals["firmware"]
    quiet_after = None
    for k in range(1, 1001):
        host.run(0.01)
        if firmware.quiescent:
            quiet_after = k * 0.01
            break
    assert quiet_after is not None and quiet_after < 5.0
    # A paced board then wakes only for its E (300 ms period; 2 deadlines each: the frame
    # starts, its bytes end), not for its 1 ms ticks: as few wake-ups as a fresh board's.
    end, wakeups = host.board.now + seconds_to_cycles(3.0), 0
    while (deadline := host.board.next_deadline()) is not None and deadline < end:
        host.run_to(deadline)
        wakeups += 1
    assert wakeups <= 2 * 3000 // 300 + 2
