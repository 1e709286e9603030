"""Quadrature decoder, position counter and M/T speed against the plant's angle."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st
from model_helpers import advance

from fpgaemu.encoder import SPEED_TIMEOUT_CYCLES, QuadratureEncoder
from fpgaemu.plant import MAX_DUTY, WheelPlant
from fpgaemu.timeline import CLOCK_HZ

MS = CLOCK_HZ // 1000


def expected_position(angle: float, counts_per_turn: int, direction: int = 1) -> int:
    # Power-up angle is the middle of count 0.
    return math.floor(angle * counts_per_turn / 360 + 0.5) * direction


def constant_speed(encoder: QuadratureEncoder, speed_dps: float, start: int, end: int,
                   angle: float) -> float:
    """Feed a constant speed in 1 ms pieces; returns the final angle."""
    cycle = start
    while cycle < end:
        nxt = min(end, cycle + MS)
        new = angle + speed_dps * (nxt - cycle) / CLOCK_HZ
        encoder.follow(cycle, angle, nxt, new)
        cycle, angle = nxt, new
    return angle


def test_counts_per_turn_is_ten_times_the_pulses() -> None:
    encoder = QuadratureEncoder(500)
    assert encoder.counts_per_turn == 5000
    encoder.follow(0, 0.0, MS, 360.0)
    assert encoder.position == 5000
    assert encoder.edges == 5000
    backwards = QuadratureEncoder(500, direction=-1)
    backwards.follow(0, 0.0, MS, 360.0)
    assert backwards.position == -5000


@given(st.lists(st.floats(-720.0, 720.0, allow_nan=False), min_size=1, max_size=30),
       st.sampled_from([1, -1]), st.integers(1, 2000))
def test_position_is_the_floor_rule_of_the_angle(angles: list[float], direction: int,
                                                 pulses: int) -> None:
    encoder = QuadratureEncoder(pulses, direction)
    previous, cycle = 0.0, 0
    for angle in angles:
        encoder.follow(cycle, previous, cycle + MS, angle)
        previous, cycle = angle, cycle + MS
        assert encoder.position == expected_position(angle, 10 * pulses, direction)


def test_a_wheel_at_rest_sits_mid_count() -> None:
    encoder = QuadratureEncoder(500)
    half = 180.0 / 5000
    encoder.follow(0, 0.0, MS, -0.99 * half)
    encoder.follow(MS, -0.99 * half, 2 * MS, 0.99 * half)
    assert encoder.edges == 0 and encoder.position == 0


@pytest.mark.parametrize("speed", [0.5, 7.0, 45.0, -45.0, 90.0])
def test_constant_speed_is_measured_to_the_clock_resolution(speed: float) -> None:
    encoder = QuadratureEncoder(500)
    angle, cycle = 0.0, 0
    readings = []
    for _ in range(1500):
        angle = constant_speed(encoder, speed, cycle, cycle + MS, angle)
        cycle += MS
        readings.append(encoder.sample_speed(cycle))
    assert readings[-1] == pytest.approx(speed, rel=1e-4)
    # Once two edges have been seen every reading is right (none is a wild first guess).
    first = next(i for i, r in enumerate(readings) if r != 0.0)
    assert all(r == pytest.approx(speed, rel=0.02) for r in readings[first:])


def test_direction_setting_flips_speed_and_position() -> None:
    encoder = QuadratureEncoder(500, direction=-1)
    constant_speed(encoder, 30.0, 0, 200 * MS, 0.0)
    assert encoder.sample_speed(200 * MS) == pytest.approx(-30.0, rel=1e-4)
    assert encoder.position == -expected_position(6.0, 5000)


def test_plant_speed_is_tracked_within_the_window() -> None:
    plant, encoder = WheelPlant(), QuadratureEncoder(500)
    cycle = 0
    history: list[float] = []  # the true speed every 0.1 ms
    schedule = [(MAX_DUTY, 600), (8000, 600), (-20000, 900)]
    checked = 0
    for duty, ms in schedule:
        plant.duty = duty
        for _ in range(ms):
            for _ in range(10):
                cycle = advance(plant, encoder, cycle, cycle + MS // 10)
                history.append(plant.speed_dps)
            measured = encoder.sample_speed(cycle)
            # Above 30 deg/s an edge comes at least every 2.4 ms, so the M/T window (from
            # the last edge before the previous sample to the last edge now) is < 5 ms.
            recent = history[-50:]
            if min(abs(v) for v in recent) > 30.0:
                assert min(recent) - 0.01 <= measured <= max(recent) + 0.01
                checked += 1
            assert encoder.position == expected_position(plant.angle_deg, 5000)
    assert checked > 1000


def test_reading_decays_without_edges_then_drops_to_zero() -> None:
    encoder = QuadratureEncoder(500)
    angle = constant_speed(encoder, 45.0, 0, 100 * MS, 0.0)
    assert encoder.sample_speed(100 * MS) == pytest.approx(45.0, rel=1e-3)
    encoder.follow(100 * MS, angle, 150 * MS, angle)  # stopped dead
    bound = 360 / 5000 * CLOCK_HZ / (150 * MS - 100 * MS)
    reading = encoder.sample_speed(150 * MS)
    assert 0 < reading <= bound * 1.05
    late = 100 * MS + SPEED_TIMEOUT_CYCLES + MS
    encoder.follow(150 * MS, angle, late, angle)
    assert encoder.sample_speed(late) == 0.0


def test_first_edge_is_only_a_reference() -> None:
    encoder = QuadratureEncoder(500)
    step = 360 / 5000
    encoder.follow(0, 0.0, MS, 0.6 * step)  # one edge after a start from rest
    assert encoder.sample_speed(MS) == 0.0
    encoder.follow(MS, 0.6 * step, 2 * MS, 1.6 * step)
    assert encoder.sample_speed(2 * MS) > 0.0


def test_no_encoder_reads_nothing() -> None:
    encoder = QuadratureEncoder(0)
    encoder.follow(0, 0.0, MS, 100.0)
    assert encoder.position == 0 and encoder.sample_speed(MS) == 0.0


def test_position_register_wraps_as_int32() -> None:
    encoder = QuadratureEncoder(500)
    turns = (2**31) // 5000 + 1
    encoder.follow(0, 0.0, MS, 360.0 * turns)
    assert encoder.position == 5000 * turns - 2**32


def test_configure_restarts_the_count_at_the_present_angle() -> None:
    encoder = QuadratureEncoder(500)
    angle = constant_speed(encoder, 45.0, 0, 100 * MS, 0.0)
    encoder.configure(1000, -1, angle)
    assert encoder.counts_per_turn == 10000 and encoder.position == 0
    assert encoder.sample_speed(100 * MS) == 0.0
    constant_speed(encoder, 45.0, 100 * MS, 200 * MS, angle)
    assert encoder.position == -expected_position(4.5, 10000)
    assert encoder.sample_speed(200 * MS) == pytest.approx(-45.0, rel=1e-3)


def test_end_stop_is_a_settable_input() -> None:
    encoder = QuadratureEncoder()
    assert encoder.end_stop is False
    encoder.end_stop = True
    assert encoder.end_stop
