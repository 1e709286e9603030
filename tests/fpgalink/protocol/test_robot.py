"""The robot description (the seed's robot as data, validated naming the key) and the
skid-steer model both sides use."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgalink.protocol.params import CHANNEL_A, CHANNEL_B
from fpgalink.protocol.robot import (
    SEED_ROBOT_TOML,
    DescriptionError,
    Pose,
    SkidSteer,
    integrate_arc,
    parse_robot,
    seed_robot,
    wrap_angle,
)


def test_the_seed_robot_is_the_thesis_robot() -> None:
    robot = seed_robot()
    assert robot.wheel_radius == 0.20 and robot.gear_ratio == 70
    assert robot.track == pytest.approx(0.66) and robot.wheelbase == pytest.approx(0.58)
    assert robot.max_wheel_speed == 90 and robot.max_linear_speed == 0.25
    assert robot.max_angular_speed == 25
    assert robot.boards == ("L", "R")
    fl, br = robot.wheel("FL"), robot.wheel("BR")
    assert (fl.board, fl.channel, fl.x, fl.y) == ("L", CHANNEL_A, 0.29, 0.33)  # REP-103
    assert (br.board, br.channel, br.x, br.y) == ("R", CHANNEL_B, -0.29, -0.33)
    assert robot.surfaces == {"ideal": 1.0, "gravel": 1.65, "marble": 1.85, "grass": 1.63}
    assert robot.chi == 1.65
    # The body (§2.5.3: 60 kg on the scales, front 25 kg, right 31.1 kg).
    assert robot.body.mass == 60.0
    cx, cy, _ = robot.body.centre_of_mass
    assert cx == pytest.approx(-0.29 + 0.58 * 25.0 / 60.0, abs=0.001)
    assert cy == pytest.approx(0.33 - 0.66 * (13.2 + 17.9) / 60.0, abs=0.001)
    names = {p.full_name(c) for p, c, _ in robot.settings_for("L")}
    assert {"TsTimerPeriod", "IncSenzResA", "Kp_Wheel_PidB"} <= names


def _with(replace: str, by: str) -> str:
    assert replace in SEED_ROBOT_TOML, replace
    return SEED_ROBOT_TOML.replace(replace, by, 1)


@pytest.mark.parametrize(("text", "needle"), [
    (_with('channel = "A"\nx = 0.29\ny = 0.33', 'channel = "C"\nx = 0.29\ny = 0.33'),
     "wheels.FL.channel: must be \"A\" or \"B\", got 'C'"),
    (_with("forward = 1", "forward = 2"), "wheels.FL.forward: must be 1 or -1"),
    (_with("x = 0.29\ny = 0.33", "x = 0.29\ny = -0.33"), "wheels.FL.y: FL is a left"),
    (_with('board = "L"\nchannel = "B"', 'board = "L"\nchannel = "A"'),
     "wheels.BL: board L channel A already drives FL"),
    (_with("wheel_radius = 0.20", "wheel_radius = -1"), "wheel_radius: must be a finite"),
    (_with("wheel_radius = 0.20", "wheel_radius = nan"), "wheel_radius: must be a finite"),
    (_with('surface = "gravel"', 'surface = "ice"'), "surface: 'ice' is not in [surfaces]"),
    (_with("gravel = 1.65", "gravel = 0.5"), "surfaces.gravel: must be a finite number ≥ 1"),
    (_with("name = ", "speed = 3\nname = "), "speed: unknown key"),
    (_with("Kp_Wheel_Pid = 520.0", "Kp_Wheel_Pid = -1.0"), "Kp_Wheel_PidA"),
    (SEED_ROBOT_TOML + "\n[board_parameters.X]\nTsTimerPeriod = 2\n",
     "board_parameters.X: no such board"),
    (SEED_ROBOT_TOML.split("[wheels.FR]")[0], "wheels.FR: missing"),
    ("name = [", "not valid TOML"),
])
def test_a_bad_description_is_refused_naming_the_key(text: str, needle: str) -> None:
    with pytest.raises(DescriptionError) as caught:
        parse_robot(text, "robot.toml")
    assert str(caught.value).startswith("robot.toml"), caught.value
    assert needle in str(caught.value)


def test_per_board_parameters_win_over_the_common_ones() -> None:
    robot = parse_robot(SEED_ROBOT_TOML + "\n[board_parameters.R]\nIncSenzCountDirectionA = -1\n")
    values = {p.full_name(c): v for p, c, v in robot.settings_for("R")}
    assert values["IncSenzCountDirectionA"] == -1 and values["IncSenzCountDirectionB"] == 1
    assert {p.full_name(c): v for p, c, v in robot.settings_for("L")}[
        "IncSenzCountDirectionA"] == 1


# --- kinematics ---------------------------------------------------------------------------------

finite = st.floats(-2.0, 2.0, allow_nan=False)


@given(finite, finite, st.floats(1.0, 3.0))
def test_wheel_speeds_and_body_twist_are_inverse(v: float, omega: float, chi: float) -> None:
    model = SkidSteer(0.2, 0.66, chi)
    left, right = model.wheel_speeds(v, omega)
    back = model.body_twist(left, right)
    assert back == pytest.approx((v, omega), abs=1e-9)


def test_expanded_track_turns_slower_than_the_wheels_say() -> None:
    ideal, gravel = SkidSteer(0.2, 0.66, 1.0), SkidSteer(0.2, 0.66, 1.65)
    _, w_ideal = ideal.body_twist(-50, 50)
    _, w_gravel = gravel.body_twist(-50, 50)
    assert math.degrees(w_ideal) == pytest.approx(30.3, abs=0.05)  # the seed's ideal figure
    assert w_gravel == pytest.approx(w_ideal / 1.65)
    # eqs. 2.21–2.23: left wheels at rest → the ICR is χ·B/2 to the left, R = v/Ω
    icr_x, icr_y, radius = gravel.icr(0.0, 50.0)
    assert icr_x == 0.0 and icr_y == pytest.approx(1.65 * 0.33) and radius == icr_y
    assert gravel.icr(30, 30) == (0.0, math.inf, math.inf)


def test_an_arc_integrates_exactly() -> None:
    pose = Pose(1.0, 2.0, 0.5)
    for _ in range(1000):  # a full circle of radius 0.5 in 1000 steps
        pose = integrate_arc(pose, math.tau * 0.5 / 1000, math.tau / 1000)
    assert (pose.x, pose.y) == pytest.approx((1.0, 2.0), abs=1e-9)
    assert pose.theta == pytest.approx(0.5, abs=1e-9)
    straight = integrate_arc(Pose(0, 0, math.pi / 2), 2.0, 0.0)
    assert (straight.x, straight.y) == pytest.approx((0.0, 2.0))


def test_angles_wrap_to_the_shortest_turn() -> None:
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-math.pi) == math.pi
    assert wrap_angle(7 * math.tau + 0.25) == pytest.approx(0.25)


def test_the_body_table_is_validated() -> None:
    base = SEED_ROBOT_TOML.replace("mass = 60.0 ", "mass = 8.0 ")
    with pytest.raises(DescriptionError, match=r"body\.mass: the four wheels"):
        parse_robot(base, "r.toml")
    bad = SEED_ROBOT_TOML.replace("imu = [0.125, -0.03, 0.11]", "imu = [0.1, 0.2]")
    with pytest.raises(DescriptionError, match=r"r.toml: body.imu: must be \[x, y, z\]"):
        parse_robot(bad, "r.toml")
    extra = SEED_ROBOT_TOML.replace("[body]\n", "[body]\ncolour = 1\n")
    with pytest.raises(DescriptionError, match=r"body\.colour: unknown key"):
        parse_robot(extra, "r.toml")
