"""The encoder through the board: the position register against the plant's wheel angle, the
M/T speed against the plant's average speed over the measuring window, and the resolution
and direction parameters (SPEC §5 ids 6–7, §6)."""

from __future__ import annotations

import itertools

import pytest
from board_helpers import MS, Host, counts_floor

from fpgaemu.timeline import CLOCK_HZ
from fpgalink import ParamAck

INT = 1


def driven(ref_a: float, ref_b: float, settings: dict[str, int] | None = None) -> Host:
    host = Host.make(settings=settings)
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    host.start_enabled()
    host.references(ref_a, ref_b)
    return host


def walk_ticks(host: Host, ticks: int) -> list[tuple[int, dict[int, tuple[int, float, float]]]]:
    """Stop at each timer tick; per channel (encoder position, plant angle, TM speed)."""
    out = []
    period = host.firmware.timer.period_cycles
    for _ in range(ticks):
        cycle = (host.board.now // period + 1) * period
        if host.keep_enabled and host.board.now % (100 * MS) == 0:
            host.enable()
        host.board.run_until(cycle)
        per_channel = {}
        for code, ch in host.firmware.channels.items():
            per_channel[code] = (ch.encoder.position, ch.plant.angle_deg, ch.speed)
        out.append((cycle, per_channel))
    return out


@pytest.mark.parametrize(("ref_a", "ref_b"), [(45.0, -30.0), (88.0, 2.0), (-5.0, 60.0)])
def test_position_is_the_wheel_angle_in_counts_within_one(ref_a: float, ref_b: float) -> None:
    host = driven(ref_a, ref_b)
    samples = walk_ticks(host, 1500)
    counts = host.firmware.channels[1].encoder.counts_per_turn
    assert counts == 5000
    for _, per_channel in samples:
        for position, angle, _ in per_channel.values():
            assert abs(position - counts_floor(angle, counts)) <= 1
    # and the wheels really went somewhere, each its own way
    _, last = samples[-1]
    assert (last[1][0] > 0) == (ref_a > 0) and (last[2][0] > 0) == (ref_b > 0)
    assert min(abs(last[1][0]), abs(last[2][0])) > 10


@pytest.mark.parametrize("reference", [45.0, -20.0, 3.0, 85.0])
def test_mt_speed_matches_the_wheels_average_speed_at_steady_state(reference: float) -> None:
    host = driven(reference, 0.0)
    host.run(2.0)
    samples = walk_ticks(host, 200)
    resolution_m_only = 360.0 / 5000 / 0.001  # one count per 1 ms period: 72 deg/s
    worst = 0.0
    for (c0, s0), (c1, s1) in itertools.pairwise(samples):
        _, angle0, _ = s0[1]
        _, angle1, measured = s1[1]
        average = (angle1 - angle0) * CLOCK_HZ / (c1 - c0)
        worst = max(worst, abs(measured - average))
    # the M/T method times edges on the 100 MHz clock: far finer than counting edges per
    # period; at steady state it agrees with the true average to a thousandth of a deg/s
    assert worst < 1e-3 * max(1.0, abs(reference))
    assert worst < resolution_m_only / 1000
    assert samples[-1][1][1][2] == pytest.approx(reference, rel=0.01)


def test_mt_speed_stays_within_the_true_speed_range_during_the_transient() -> None:
    host = driven(60.0, 0.0)
    speeds: list[float] = []
    measured: list[float] = []
    period = host.firmware.timer.period_cycles
    for _ in range(500):
        host.board.run_until((host.board.now // period + 1) * period)
        ch = host.firmware.channels[1]
        speeds.append(ch.plant.speed_dps)
        measured.append(ch.speed)
    for k in range(20, 500):
        window = speeds[k - 5:k + 1]
        assert min(window) - 1e-6 <= measured[k] <= max(window) + 1e-6


def test_resolution_parameter_sets_counts_per_turn() -> None:
    host = Host.make()
    assert isinstance(host.set(6, 1, INT, 100), ParamAck)  # 1000 counts per turn
    assert isinstance(host.set(6, 2, INT, 2000), ParamAck)  # 20000 counts per turn
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    host.start_enabled()
    host.references(45.0, 45.0)
    samples = walk_ticks(host, 1500)
    assert host.firmware.channels[1].encoder.counts_per_turn == 1000
    assert host.firmware.channels[2].encoder.counts_per_turn == 20000
    for _, per_channel in samples:
        pos_a, angle_a, _ = per_channel[1]
        pos_b, angle_b, _ = per_channel[2]
        assert abs(pos_a - counts_floor(angle_a, 1000)) <= 1
        assert abs(pos_b - counts_floor(angle_b, 20000)) <= 1
    _, last = samples[-1]
    # about the same wheel motion (each loop sees its own quantisation), 20× the counts
    assert last[2][0] == pytest.approx(20 * last[1][0], rel=0.05)
    assert last[1][2] == pytest.approx(45.0, rel=0.02)
    assert last[2][2] == pytest.approx(45.0, rel=0.02)


def test_direction_and_resolution_changes_restart_the_count_from_the_present_angle() -> None:
    host = driven(30.0, 30.0)
    host.run(1.0)
    angle_at_change = host.firmware.channels[1].plant.angle_deg
    assert isinstance(host.set(7, 1, INT, -1), ParamAck)
    angle_at_change = (angle_at_change + host.firmware.channels[1].plant.angle_deg) / 2
    # the loop now sees the opposite sign: clamp so the runaway stays gentle
    assert isinstance(host.set(5, 1, INT, 4000), ParamAck)
    samples = walk_ticks(host, 500)
    for _, per_channel in samples:
        position, angle, _speed = per_channel[1]
        assert abs(-position - counts_floor(angle - angle_at_change, 5000)) <= 2
    _, last = samples[-1]
    assert last[1][0] < 0 and last[1][2] < 0
    assert host.firmware.channels[1].plant.speed_dps > 0


def test_zero_resolution_reads_nothing() -> None:
    host = Host.make(settings={"IncSenzResA": 0, "MaxControlSignalA": 3000})
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    host.start_enabled()
    host.references(20.0, 0.0)
    host.run(1.0)
    assert all(tm.a.position == 0 and tm.a.speed == 0.0 for tm in host.telemetry)
    # the wheel turns, the loop is blind: the output runs to the clamp
    assert host.telemetry[-1].a.pwm == 3000
    assert host.firmware.channels[1].plant.angle_deg > 1.0
