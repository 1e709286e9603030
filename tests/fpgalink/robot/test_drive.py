"""Body commands to wheel references: the same reference for a side's two wheels, limits
that keep the curvature, nothing non-finite."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgalink.protocol import LocalProtocolError
from fpgalink.protocol.robot import SEED_ROBOT_TOML, parse_robot, seed_robot
from fpgalink.robot.drive import wheel_command

ROBOT = seed_robot()


def test_a_side_gets_one_reference_and_the_boards_get_theirs() -> None:
    command = wheel_command(ROBOT, 0.1, math.radians(10))
    assert command.scale == 1.0
    left_a, left_b = command.references["L"]
    right_a, right_b = command.references["R"]
    assert left_a == left_b == command.left_dps and right_a == right_b == command.right_dps
    # 10 deg/s on gravel (χ 1.65): the sides differ by ω·χ·B / r
    expected = math.degrees(math.radians(10) * 1.65 * 0.66 / 0.2)
    assert command.right_dps - command.left_dps == pytest.approx(expected)
    assert (command.left_dps + command.right_dps) / 2 == pytest.approx(math.degrees(0.1 / 0.2))


def test_a_mirrored_wheel_gets_the_opposite_sign() -> None:
    mirrored = parse_robot(SEED_ROBOT_TOML.replace(
        '[wheels.FL]\nboard = "L"\nchannel = "A"\nx = 0.29\ny = 0.33\nforward = 1',
        '[wheels.FL]\nboard = "L"\nchannel = "A"\nx = 0.29\ny = 0.33\nforward = -1'))
    command = wheel_command(mirrored, 0.1, 0.0)
    ref_a, ref_b = command.references["L"]
    assert ref_a == -ref_b and ref_b > 0


@given(st.floats(-5, 5, allow_nan=False), st.floats(-10, 10, allow_nan=False))
def test_limits_scale_the_command_and_keep_its_curvature(v: float, omega: float) -> None:
    command = wheel_command(ROBOT, v, omega)
    assert 0.0 < command.scale <= 1.0
    assert abs(command.v) <= ROBOT.max_linear_speed + 1e-12
    assert abs(command.omega) <= ROBOT.max_angular_speed_rad + 1e-12
    assert max(abs(command.left_dps), abs(command.right_dps)) <= ROBOT.max_wheel_speed + 1e-9
    assert command.v == pytest.approx(v * command.scale, abs=1e-12)
    assert command.omega == pytest.approx(omega * command.scale, abs=1e-12)
    if command.scale < 1.0:  # something is at its limit
        at_limit = (abs(command.v) == pytest.approx(ROBOT.max_linear_speed)
                    or abs(command.omega) == pytest.approx(ROBOT.max_angular_speed_rad)
                    or max(abs(command.left_dps), abs(command.right_dps))
                    == pytest.approx(ROBOT.max_wheel_speed))
        assert at_limit


def test_a_wheel_limit_binds_on_a_fast_turn_with_speed() -> None:
    command = wheel_command(ROBOT, 0.25, math.radians(25))  # both robot limits, exactly
    assert max(abs(command.left_dps), abs(command.right_dps)) == pytest.approx(90.0)
    assert command.scale < 1.0
    assert command.omega / command.v == pytest.approx(math.radians(25) / 0.25)


@pytest.mark.parametrize(("v", "omega"), [(math.nan, 0.0), (0.0, math.inf),
                                          (-math.inf, 0.0)])
def test_non_finite_commands_are_refused(v: float, omega: float) -> None:
    with pytest.raises(LocalProtocolError, match="finite"):
        wheel_command(ROBOT, v, omega)


def test_a_sides_radius_multiplier_turns_that_side_slower_for_the_same_ground_speed() -> None:
    from fpgalink.protocol.robot import SkidSteer

    description = seed_robot()
    model = description.kinematics()
    larger_left = SkidSteer(model.wheel_radius, model.track, model.chi, 1.25, 1.0)
    plain = wheel_command(description, 0.1, 0.0, model)
    command = wheel_command(description, 0.1, 0.0, larger_left)
    assert command.left_dps == pytest.approx(plain.left_dps / 1.25)
    assert command.right_dps == pytest.approx(plain.right_dps)
    assert larger_left.body_twist(command.left_dps, command.right_dps) == pytest.approx(
        (0.1, 0.0))
