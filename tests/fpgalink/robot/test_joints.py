"""Wheel joint states from telemetry: the seed URDF's joint names and order, forward-positive
rad and rad/s whatever a board's own sign, effort from the current through TorqueCoef."""

from __future__ import annotations

import math

from fpgalink.protocol import ChannelTelemetry, Telemetry
from fpgalink.protocol.robot import SEED_ROBOT_TOML, parse_robot, seed_robot
from fpgalink.robot.joints import joint_states

PER_TURN = {(board, ch): 5000 for board in ("L", "R") for ch in (1, 2)}
TORQUE = {(board, ch): 0.2 for board in ("L", "R") for ch in (1, 2)}


def channel(position: int, speed: float, current: float) -> ChannelTelemetry:
    return ChannelTelemetry(position, speed, current, 0, 0.0, 1)


def samples() -> dict[str, Telemetry]:
    return {"L": Telemetry(1000, channel(2500, 90.0, 1.5), channel(-1250, -45.0, -0.5)),
            "R": Telemetry(1000, channel(5000, 30.0, 2.0), channel(0, 0.0, 0.0))}


def test_the_four_wheels_in_urdf_order_in_si_units() -> None:
    states = joint_states(seed_robot(), samples(), PER_TURN, TORQUE)
    assert states is not None
    assert states.names == ("FL", "BL", "FR", "BR")
    assert states.position == (math.pi, -math.pi / 2, math.tau, 0.0)
    assert states.velocity == (math.radians(90.0), math.radians(-45.0), math.radians(30.0),
                               0.0)
    assert states.effort == (1.5 * 0.2, -0.5 * 0.2, 2.0 * 0.2, 0.0)


def test_a_wheel_mounted_the_other_way_is_reported_forward_positive() -> None:
    flipped = SEED_ROBOT_TOML.replace('[wheels.FR]\nboard = "R"\nchannel = "A"\nx = 0.29\n'
                                      'y = -0.33\nforward = 1',
                                      '[wheels.FR]\nboard = "R"\nchannel = "A"\nx = 0.29\n'
                                      'y = -0.33\nforward = -1')
    assert flipped != SEED_ROBOT_TOML
    states = joint_states(parse_robot(flipped), samples(), PER_TURN, TORQUE)
    assert states is not None
    assert states.position[2] == -math.tau
    assert states.velocity[2] == -math.radians(30.0)
    assert states.effort[2] == -2.0 * 0.2


def test_nothing_until_every_board_has_sent_a_sample() -> None:
    only_left = {"L": samples()["L"]}
    assert joint_states(seed_robot(), only_left, PER_TURN, TORQUE) is None


def test_unknown_resolution_or_torque_coefficient_is_nan_not_a_guess() -> None:
    states = joint_states(seed_robot(), samples(), {}, {})
    assert states is not None
    assert all(math.isnan(p) for p in states.position)
    assert all(math.isnan(e) for e in states.effort)
    assert states.velocity[0] == math.radians(90.0)


def test_sample_sets_use_each_sample_once_and_keep_to_the_period() -> None:
    from fpgalink.robot.joints import SampleSets

    sets = SampleSets(("L", "R"), min_period=0.01)
    one = samples()
    assert sets.add("L", one["L"], 0.000) is None
    assert sets.add("R", one["R"], 0.001) == one  # complete: out with the sample that did it
    assert sets.add("L", one["L"], 0.002) is None
    assert sets.add("R", one["R"], 0.003) is None  # complete, but too soon
    assert sets.add("R", one["R"], 0.0106) == one  # 9.6 ms: within the half-ms slack
    assert sets.add("R", one["R"], 0.05) is None  # L has nothing new
