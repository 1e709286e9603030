"""The position controller (seed Algorithm 1): on an ideal unicycle (the reference model)
from every direction, then on the emulated robot from several starts."""

from __future__ import annotations

import math

import pytest

from fpgalink.protocol.robot import Pose, integrate_arc
from fpgalink.robot.goto import GoTo, GoToSettings, Phase
from tests.support.emulated import RobotSim

SETTINGS = GoToSettings()


def unicycle(goal: GoTo, pose: Pose, dt: float = 0.01, limit_s: float = 60.0) -> tuple[
        Pose, list[Phase]]:
    """The reference model: the body does exactly what is commanded."""
    phases: list[Phase] = []
    t = 0.0
    while t < limit_s and not goal.done:
        step = goal.step(pose, t)
        if not phases or phases[-1] is not step.phase:
            phases.append(step.phase)
        assert abs(step.v) <= SETTINGS.max_speed + 1e-12
        assert abs(step.omega) <= SETTINGS.max_turn_rate + 1e-12
        pose = integrate_arc(pose, step.v * dt, step.omega * dt)
        t += dt
    return pose, phases


@pytest.mark.parametrize("heading_deg", range(-180, 180, 30))
def test_arrives_from_any_heading(heading_deg: int) -> None:
    goal = GoTo(2.0, 1.0)
    pose, phases = unicycle(goal, Pose(0.0, 0.0, math.radians(heading_deg)))
    assert goal.done
    assert math.hypot(pose.x - 2.0, pose.y - 1.0) < SETTINGS.position_tolerance
    initial_error = abs(math.remainder(math.atan2(1.0, 2.0) - math.radians(heading_deg),
                                       math.tau))
    turns_first = initial_error > SETTINGS.heading_tolerance / 2
    assert (phases[0] is Phase.TURN) == turns_first
    assert Phase.DRIVE in phases and phases[-1] is Phase.ARRIVED


def test_a_goal_behind_turns_first_then_drives() -> None:
    goal = GoTo(-1.0, 0.0)
    first = goal.step(Pose(), 0.0)
    assert first.phase is Phase.TURN and first.v == 0.0 and first.omega != 0.0
    pose, _ = unicycle(goal, Pose())
    assert math.hypot(pose.x + 1.0, pose.y) < SETTINGS.position_tolerance


def test_a_final_heading_is_turned_to() -> None:
    goal = GoTo(1.0, 0.0, math.radians(90))
    pose, phases = unicycle(goal, Pose())
    assert Phase.ALIGN in phases
    assert abs(math.degrees(math.remainder(pose.theta - math.pi / 2, math.tau))) < 3.0


def test_distance_is_weighted_by_the_inverse_heading_error() -> None:
    aligned = GoTo(0.25, 0.0)  # close enough that the speed is below its limit
    aligned.step(Pose(0, 0, 0), 0.0)  # TURN → DRIVE at once: aligned
    off = GoTo(0.25, 0.0)
    off.step(Pose(0, 0, 0), 0.0)
    v_aligned = aligned.step(Pose(0, 0, 0.0), 0.01).v
    v_off = off.step(Pose(0, 0, math.radians(8)), 0.01).v
    assert 0 < v_off < v_aligned


def test_goal_must_be_finite() -> None:
    with pytest.raises(ValueError, match="finite"):
        GoTo(math.nan, 0.0)


@pytest.mark.parametrize(("start", "goal"), [
    (Pose(0.0, 0.0, 0.0), (1.5, 0.5)),
    (Pose(0.0, 0.0, 0.0), (-1.0, 0.2)),  # behind the robot
    (Pose(1.0, 1.0, math.radians(-120)), (0.0, 0.0)),
])
def test_the_emulated_robot_arrives_within_tolerance(start: Pose, goal: tuple[float, float]
                                                     ) -> None:
    sim = RobotSim.make("gravel", pose=start)
    controller = sim.go_to(*goal)
    assert controller.done
    truth = sim.truth  # at rest, as measured by the emulator
    assert math.hypot(truth.x - goal[0], truth.y - goal[1]) < SETTINGS.position_tolerance
