"""Odometry: from encoder counts (wrap-safe), checked on made-up counts against exact
geometry and against the emulated robot's true pose."""

from __future__ import annotations

import math

import pytest

from fpgalink.protocol import ChannelTelemetry, Telemetry
from fpgalink.protocol.robot import Pose, seed_robot
from fpgalink.robot.odometry import QUEUED_SAMPLES, Odometry, count_delta
from tests.support.emulated import RobotSim

ROBOT = seed_robot().on_surface("ideal")
COUNTS_PER_TURN = 5000  # IncSenzRes 500


def sample(t_us: int, a: int, b: int, speed: float = 0.0) -> Telemetry:
    return Telemetry(t_us, ChannelTelemetry(a, speed, 0.0, 0, 0.0, 1),
                     ChannelTelemetry(b, speed, 0.0, 0, 0.0, 1))


def odometry(start: int = 0) -> Odometry:
    odo = Odometry(ROBOT)
    for board in ("L", "R"):
        for channel in (1, 2):
            odo.set_resolution(board, channel, 500)
    odo.update("L", sample(0, start, start))
    odo.update("R", sample(0, start, start))
    return odo


def drive_counts(odo: Odometry, left: int, right: int, steps: int, start: int = 0) -> None:
    """Both sides advance by ``left``/``right`` counts in ``steps`` equal steps."""
    for k in range(1, steps + 1):
        l_count = (start + round(left * k / steps) + 2**31) % 2**32 - 2**31
        r_count = (start + round(right * k / steps) + 2**31) % 2**32 - 2**31
        odo.update("L", sample(k * 1000, l_count, l_count))
        odo.update("R", sample(k * 1000, r_count, r_count))


def test_count_differences_across_the_i32_wrap() -> None:
    assert count_delta(-2**31 + 5, 2**31 - 5) == 10
    assert count_delta(2**31 - 5, -2**31 + 5) == -10
    assert count_delta(7, 3) == 4


@pytest.mark.parametrize("start", [0, 2**31 - 2_000])  # the second crosses the wrap
def test_a_straight_line_from_counts(start: int) -> None:
    odo = odometry(start)
    turns = 2.0 / (math.tau * 0.2)  # 2 m of wheel rim
    drive_counts(odo, round(turns * COUNTS_PER_TURN), round(turns * COUNTS_PER_TURN), 400,
                 start)
    assert odo.pose.x == pytest.approx(2.0, abs=2e-4)
    assert odo.pose.y == pytest.approx(0.0, abs=1e-9) and odo.pose.theta == pytest.approx(0.0)
    assert odo.distance == pytest.approx(2.0, abs=2e-4)


def test_a_turn_in_place_adds_no_path() -> None:
    odo = odometry()
    rim = math.pi / 2 * 0.33  # a quarter turn: each side rolls ω·B/2 · t
    counts = round(rim / (math.tau * 0.2) * COUNTS_PER_TURN)
    drive_counts(odo, -counts, counts, 100)
    assert odo.pose.theta == pytest.approx(math.pi / 2, abs=1e-3)
    assert math.hypot(odo.pose.x, odo.pose.y) < 1e-9
    assert odo.distance == pytest.approx(0.0, abs=1e-9)


def test_the_covariance_grows_with_distance_and_turning() -> None:
    odo = odometry()
    drive_counts(odo, 2000, 2000, 20)
    after_line = [row[:] for row in odo.covariance]
    assert after_line[0][0] > 0 and after_line[2][2] > 0
    drive_counts(odo, -2000, 2000, 20, start=2000)
    assert odo.covariance[2][2] > after_line[2][2]
    for i in range(3):  # a covariance stays symmetric with a non-negative diagonal
        assert odo.covariance[i][i] >= 0
        for j in range(3):
            assert odo.covariance[i][j] == pytest.approx(odo.covariance[j][i])


def test_odometry_needs_the_boards_resolution_first() -> None:
    odo = Odometry(ROBOT)
    with pytest.raises(ValueError, match="resolution"):
        odo.update("L", sample(0, 0, 0))
    with pytest.raises(ValueError, match="positive"):
        odo.set_resolution("L", 1, 0)


# --- against the emulator's truth ---------------------------------------------------------------


def _errors(sim: RobotSim) -> tuple[float, float]:
    odo, truth = sim.odometry.pose, sim.truth
    heading = abs(math.degrees(math.remainder(odo.theta - truth.theta, math.tau)))
    return math.hypot(odo.x - truth.x, odo.y - truth.y), heading


@pytest.mark.parametrize("surface", ["ideal", "gravel"])
def test_a_two_metre_line_against_the_truth(surface: str) -> None:
    sim = RobotSim.make(surface)
    sim.drive(0.2, 0.0)
    sim.run(10.0)
    sim.drive(0.0, 0.0)
    sim.run(1.0)
    travelled = sim.robot.body.distance
    assert travelled == pytest.approx(2.0, rel=0.05)
    position, heading = _errors(sim)
    assert position <= 0.02 * travelled and heading <= 3.0


@pytest.mark.parametrize("surface", ["ideal", "gravel"])
def test_a_one_metre_square_against_the_truth(surface: str) -> None:
    sim = RobotSim.make(surface)
    for x, y in ((1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0)):
        assert sim.go_to(x, y).done
    travelled = sim.robot.body.distance
    assert travelled > 3.8
    position, heading = _errors(sim)
    assert position <= 0.02 * travelled and heading <= 3.0


def test_odometry_with_the_wrong_surface_is_visibly_wrong() -> None:
    # The check above could pass by accident if odometry copied the truth; with the ideal
    # χ on gravel the heading is off by the factor the seed measured.
    sim = RobotSim.make("gravel", odometry_surface="ideal")
    sim.drive(0.0, math.radians(20))
    sim.run(4.0)
    turned_truth = sim.truth.theta
    turned_odometry = sim.odometry.pose.theta
    assert turned_odometry / turned_truth == pytest.approx(1.65, rel=0.02)


def test_a_pose_to_start_from() -> None:
    sim = RobotSim.make("ideal", pose=Pose(3.0, -1.0, math.pi / 2))
    sim.drive(0.2, 0.0)
    sim.run(2.0)
    assert sim.odometry.pose.x == pytest.approx(3.0, abs=1e-3)
    assert sim.odometry.pose.y > -1.0 + 0.3


# --- the running totals and the covariance follow motion, not jitter --------------------------


def test_jitter_of_whole_counts_and_sample_pairing_adds_nothing_to_the_totals() -> None:
    # A straight line whose sides come in whole counts, one board's samples a period
    # behind the other's: each step's turn alternates left and right and cancels.
    odo = odometry()
    per_ms = 1.25  # counts a millisecond, both sides: 0.31 mm/ms
    for k in range(1, 4001):
        odo.update("L", sample(k * 1000, math.floor(per_ms * k), math.floor(per_ms * k)))
        odo.update("R", sample(k * 1000, math.floor(per_ms * (k - 1) + 0.5),
                               math.floor(per_ms * (k - 1) + 0.5)))
    assert odo.pose.theta == pytest.approx(0.0, abs=1e-3)
    assert odo.turned < math.radians(0.1)
    assert odo.distance == pytest.approx(odo.pose.x, abs=1e-3)


def test_the_totals_and_heading_sigma_of_the_seeds_runs_match_the_model() -> None:
    # Against the emulated robot (whole counts, the PID's ripple, and the two boards'
    # samples paired up to a period apart, as two ports read in turn deliver them): a 2 m
    # line turns nothing, a 200° turn in place travels nothing, and the heading's σ after
    # the line is the documented motion model's, √(k_dθ · 2 m).
    sim = RobotSim.make("gravel", arrival_jitter_seed=7)
    sim.drive(0.2, 0.0)
    sim.run(10.0)
    sim.drive(0.0, 0.0)
    sim.run(1.0)
    travelled = sim.robot.body.distance
    assert sim.odometry.distance == pytest.approx(travelled, rel=0.01)
    assert math.degrees(sim.odometry.turned) < 1.0
    model = math.sqrt(ROBOT.odometry.drift_noise * sim.odometry.distance)
    sigma = math.sqrt(sim.odometry.covariance[2][2])
    assert sigma == pytest.approx(model, rel=0.05)  # 0.81° for 2 m

    sim = RobotSim.make("gravel", arrival_jitter_seed=8)
    sim.drive(0.0, math.radians(20))
    turned_truth = 0.0
    for _ in range(4):  # the truth's heading is wrapped: summed in quarters
        before = sim.truth.theta
        sim.run(2.5)
        turned_truth += math.remainder(sim.truth.theta - before, math.tau)
    sim.drive(0.0, 0.0)
    before = sim.truth.theta
    sim.run(1.0)
    turned_truth += math.remainder(sim.truth.theta - before, math.tau)
    assert math.degrees(turned_truth) > 180
    assert sim.odometry.turned == pytest.approx(turned_truth, rel=0.02)
    assert sim.odometry.distance < 0.005


def test_a_restarted_board_is_a_new_reference_not_a_jump() -> None:
    odo = odometry()
    drive_counts(odo, 2000, 2000, 20)
    x = odo.pose.x
    odo.restart("L")
    odo.update("R", sample(21_000, 2100, 2100))  # R moved while L was away: dropped
    odo.update("L", sample(0, 0, 0))  # L counts from 0 again: a reference
    odo.update("R", sample(22_000, 2200, 2200))
    odo.update("L", sample(1000, 100, 100))
    step = 100 / COUNTS_PER_TURN * math.tau * 0.2
    assert odo.pose.x == pytest.approx(x + step, abs=1e-9)
    assert odo.pose.theta == pytest.approx(0.0, abs=1e-12)
    assert odo.reanchors == 1


def test_a_restart_seen_only_in_the_samples_is_a_new_reference_not_a_jump() -> None:
    # Issue 37.13: the board's clock going back is its restart, whether or not its link's
    # event came first (a loaded host's odometry task may read the restarted board's first
    # samples before the event is noticed, or the event is never there: a recording).
    odo = odometry()
    drive_counts(odo, 2000, 2000, 20)
    x = odo.pose.x
    odo.update("R", sample(21_000, 2100, 2100))  # R moved while L was away: dropped
    odo.update("L", sample(3000, 7, 7))  # L's clock went back: counts from 0 again
    odo.update("R", sample(22_000, 2200, 2200))
    odo.update("L", sample(4000, 107, 107))
    step = 100 / COUNTS_PER_TURN * math.tau * 0.2
    assert odo.pose.x == pytest.approx(x + step, abs=1e-9)
    assert odo.pose.theta == pytest.approx(0.0, abs=1e-12)
    assert odo.reanchors == 1
    # Its clock wrapping (every 71.6 min) is no restart: the counts go on.
    odo = Odometry(ROBOT)
    for board in ("L", "R"):
        for channel in (1, 2):
            odo.set_resolution(board, channel, 500)
    for k, t_us in enumerate((2**32 - 3000, 2**32 - 2000, 2**32 - 1000, 0, 1000)):
        odo.update("L", sample(t_us, 100 * k, 100 * k))
        odo.update("R", sample(t_us, 100 * k, 100 * k))
    assert odo.pose.x == pytest.approx(4 * step, abs=1e-9)
    assert odo.reanchors == 0


def test_a_sides_radius_multiplier_scales_that_sides_distance_only() -> None:
    # The left wheels 2 % larger (diff_drive_controller's left_wheel_radius_multiplier):
    # equal counts on both sides are a curve to the right, its mean path 1 % longer.
    from fpgalink.protocol.robot import SkidSteer

    model = ROBOT.kinematics()
    odo = odometry()
    odo.set_kinematics(ROBOT, SkidSteer(model.wheel_radius, model.track, model.chi, 1.02, 1.0))
    turns = 2.0 / (math.tau * 0.2)
    drive_counts(odo, round(turns * COUNTS_PER_TURN), round(turns * COUNTS_PER_TURN), 400)
    assert odo.distance == pytest.approx(2.0 * 1.01, abs=2e-4)
    assert odo.pose.theta == pytest.approx(-2.0 * 0.02 / model.effective_track, abs=1e-4)


# --- samples paired by the board time they close, not by the order they are handled in -----


def counted(t_us: int, a: int, b: int, counter: int) -> Telemetry:
    return Telemetry(t_us, ChannelTelemetry(a, 0.0, 0.0, 0, 0.0, 1),
                     ChannelTelemetry(b, 0.0, 0.0, 0, 0.0, 1), counter)


def arc_samples(periods: int, lost: frozenset[int] = frozenset(), replies: int = 0
                ) -> dict[str, list[Telemetry]]:
    """An arc: L 12 counts a period, R 20, from period 1 (0 is the reference), each board's
    message counter from 99,990 so that it wraps; the periods in ``lost`` missing from L;
    ``replies``: L answered that many requests between each two samples (its counter goes
    on by one more each), which changes nothing of its periods."""
    out: dict[str, list[Telemetry]] = {"L": [], "R": []}
    for board, per in (("L", 12), ("R", 20)):
        step = 1 + (replies if board == "L" else 0)
        for k in range(periods + 1):
            if board == "L" and k in lost:
                continue
            out[board].append(counted(k * 1000, per * k, per * k,
                                      (99_990 + step * k) % 100_000))
    return out


def fresh() -> Odometry:
    odo = Odometry(ROBOT)
    for board in ("L", "R"):
        for channel in (1, 2):
            odo.set_resolution(board, channel, 500)
    return odo


def handled_in_turn(samples: dict[str, list[Telemetry]], batch: int) -> Odometry:
    """Each board's samples ``batch`` at a time, the boards in turn (1: as they come)."""
    odo = fresh()
    left, right = samples["L"], samples["R"]
    for start in range(0, max(len(left), len(right)), batch):
        for s in left[start:start + batch]:
            odo.update("L", s)
        for s in right[start:start + batch]:
            odo.update("R", s)
    return odo


def test_reads_in_batches_step_the_body_as_samples_one_at_a_time_do() -> None:
    samples = arc_samples(600)
    one = handled_in_turn(samples, 1)
    assert one.steps == 600 and one.pose.theta > 0.05
    for batch in (2, 10, 37):
        odo = handled_in_turn(samples, batch)
        assert odo.pose == one.pose  # the same steps, to the last bit
        assert odo.steps == one.steps and odo.queued == {"L": 0, "R": 0}
        assert odo.covariance == one.covariance


def test_a_lost_sample_is_its_successors_periods_shared_not_a_shifted_pairing() -> None:
    # L's samples of periods 100 and 101 are lost: its next one closes three milliseconds of
    # its clock, and R's three steps take a third of it each, so every later step still
    # pairs the same period. The arc's motion is even, so the pose is the one with nothing
    # lost.
    whole = handled_in_turn(arc_samples(600), 1)
    odo = handled_in_turn(arc_samples(600, frozenset({100, 101})), 1)
    assert odo.steps == whole.steps
    assert odo.pose.x == pytest.approx(whole.pose.x, abs=1e-12)
    assert odo.pose.y == pytest.approx(whole.pose.y, abs=1e-12)
    assert odo.pose.theta == pytest.approx(whole.pose.theta, abs=1e-12)


def test_replies_between_samples_and_a_repeated_sample_shift_no_pairing() -> None:
    # A board's replies take message counter values too, so its counter is no count of
    # periods: L answering a request between every two samples changes nothing. Nor does a
    # sample handed over twice (the same board time: no new stretch).
    whole = handled_in_turn(arc_samples(600), 1)
    assert handled_in_turn(arc_samples(600, replies=1), 10).pose == whole.pose
    samples = arc_samples(600)
    samples["L"].insert(300, samples["L"][299])
    odo = handled_in_turn(samples, 1)
    assert odo.pose == whole.pose and odo.queued == {"L": 0, "R": 0}


def test_a_silent_board_leaves_the_others_motion_queued_and_bounded_none_lost() -> None:
    # R goes silent for 3 s while L's samples go on, a straight line: L's motion waits,
    # bounded, and R's next sample closes the whole silence, so the line stays straight and
    # no motion is lost.
    odo = fresh()
    per = 10
    for k in range(0, 5001):
        odo.update("L", counted(k * 1000, per * k, per * k, k))
        if k <= 1000 or k >= 4000:
            odo.update("R", counted(k * 1000, per * k, per * k, k))
        if 1000 < k < 4000:
            assert odo.queued["L"] <= QUEUED_SAMPLES and odo.queued["R"] == 0
    assert odo.queued == {"L": 0, "R": 0}
    metres = 5000 * per / COUNTS_PER_TURN * math.tau * 0.2
    assert odo.pose.x == pytest.approx(metres, abs=1e-9)
    assert odo.pose.theta == pytest.approx(0.0, abs=1e-12)
    assert odo.pose.y == pytest.approx(0.0, abs=1e-9)
