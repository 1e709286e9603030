"""Sample stamping, sans-I/O: sets of one sample per board, each stamped on the reader's
clock by the board's own time, the odometry with its stamp, a ramp's commands stamped at
their steps, a clock not started yet, a board's restart."""

from __future__ import annotations

import itertools

from fpgalink.protocol import ChannelTelemetry, Telemetry
from fpgalink.protocol.robot import Pose, seed_robot
from fpgalink.robot.drive import wheel_command
from fpgalink.robot.odometry import OdometryState
from fpgalink.robot.stamping import SampleStamper, StampedSet

STATE = OdometryState(Pose(), 0.0, 0.0, ((0.0,) * 3,) * 3, 0.0, 0.0)
DELAY_NS = 700_000  #: every sample arrives 0.7 ms after it was taken


def sample(t_us: int) -> Telemetry:
    channel = ChannelTelemetry(0, 0.0, 0.0, 0, 0.0, 1)
    return Telemetry(t_us, channel, channel)


def feed(stamper: SampleStamper, board: str, t_us: int, epoch_ns: int = 10**18
         ) -> StampedSet | None:
    taken_ns = epoch_ns + t_us * 1000
    return stamper.add(board, sample(t_us), (taken_ns + DELAY_NS) / 1e9,
                       lambda received: round(received * 1e9), lambda: STATE)


def test_a_set_per_pair_of_samples_stamped_on_each_boards_clock() -> None:
    stamper = SampleStamper(("L", "R"))
    sets: list[StampedSet] = []
    for k in range(200):
        for board, offset in (("L", 0), ("R", 300)):
            got = feed(stamper, board, k * 1000 + offset)
            if got is not None:
                sets.append(got)
    assert len(sets) == 200
    last = sets[-1]
    assert last.samples["L"].t_us == 199_000 and last.samples["R"].t_us == 199_300
    # Each sample on the reader's clock when it was taken, but for the delay no clock can
    # tell from a constant one; the set's stamp the first board's, the odometry's the
    # earliest of the two.
    assert abs(last.stamps["L"] - (10**18 + 199_000_000 + DELAY_NS)) < 1000
    assert abs(last.stamps["R"] - last.stamps["L"] - 300_000) < 1000
    assert last.stamp == last.stamps["L"] == last.odometry_stamp
    assert all(b.odometry_stamp > a.odometry_stamp for a, b in itertools.pairwise(sets))
    assert last.odometry is STATE


def test_a_clock_not_started_stamps_nothing() -> None:
    # ROS time under use_sim_time before the first /clock: the set is given (the emulated
    # robot's /clock ticks on it), unstamped; the boards' clocks are not anchored at 0.
    stamper = SampleStamper(("L", "R"))
    assert stamper.add("L", sample(0), 1.0, lambda received: 0, lambda: STATE) is None
    got = stamper.add("R", sample(0), 1.0, lambda received: 0, lambda: STATE)
    assert got is not None and not got.clocked and stamper.unclocked == 1
    feed(stamper, "L", 1000)
    got = feed(stamper, "R", 1000)
    assert got is not None and got.clocked
    assert abs(got.stamps["L"] - (10**18 + 1_000_000 + DELAY_NS)) < 1000


def test_a_ramps_commands_are_stamped_at_their_steps() -> None:
    stamper = SampleStamper(("L", "R"))
    feed(stamper, "L", 0)
    feed(stamper, "R", 0)
    command = wheel_command(seed_robot(), 0.05, 0.0)
    stamper.drove(4000, command)
    feed(stamper, "L", 5000)
    got = feed(stamper, "R", 5000)
    assert got is not None
    ((stamp, driven),) = got.driven
    assert driven is command and got.stamp - stamp == 1_000_000


def test_a_restarted_board_is_mapped_afresh() -> None:
    stamper = SampleStamper(("L", "R"))
    for k in range(10):
        feed(stamper, "L", 5_000_000 + k * 1000)
        feed(stamper, "R", 5_000_000 + k * 1000)
    stamper.restart("L")
    # L counts from 0 again: its samples are still stamped when they were taken.
    epoch = 10**18 + 5_010_000_000
    feed(stamper, "L", 0, epoch)
    got = feed(stamper, "R", 5_010_000, 10**18)
    assert got is not None
    assert abs(got.stamps["L"] - got.stamps["R"]) < 1_000_000


def test_a_ramps_steps_keep_their_spacing_while_a_late_start_is_worked_off() -> None:
    # The first samples came 0.2 s late (a loaded start): the board clock's mapping works
    # that off at 25 % of the board time passed, so consecutive samples' stamps stay at
    # least 75 % of their spacing. A ramp stepped every 10 ms of board time is stamped at
    # each step's own sample and keeps that; stamped back from the set it went out with
    # (sets 10 to 19 ms of board time apart), two steps came 42.5 ms out of order here, and
    # 5 ms apart in the ROS describe scenario's ramp.
    stamper = SampleStamper(("L", "R"), min_period=0.0105)
    command = wheel_command(seed_robot(), 0.05, 0.0)
    driven: list[int] = []
    for k in range(600):
        t_us = 1_000_000 + k * 1000
        if k % 10 == 0:
            stamper.drove(t_us, command)
        late = max(0.2 - k * 0.001, 0.0007)  # the backlog read out at twice real time
        for board in ("L", "R"):
            got = stamper.add(board, sample(t_us), t_us / 1e6 + late,
                              lambda received: round(received * 1e9), lambda: STATE)
            if got is not None:
                driven += [stamp for stamp, _ in got.driven]
    gaps = [b - a for a, b in itertools.pairwise(driven)]
    assert len(gaps) > 40
    assert min(gaps) >= 0.75 * 10_000_000, sorted(gaps)[:5]
