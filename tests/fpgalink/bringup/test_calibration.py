"""Calibration arithmetic with known answers (χ from a turn, the radius from a run, a gyro's
heading with its bias taken out, headings unwrapped through ±π), what it refuses, and the
robot-file and parameter-set edits that save the results: values set in place with their
comments kept, missing keys and tables added, the result parsed again, an edit that cannot
be made refused."""

from __future__ import annotations

import math

import pytest

from fpgalink.bringup.calibration import (
    CalibrationError,
    GyroHeading,
    chi_from_turn,
    radius_from_run,
    unwrapped_change,
)
from fpgalink.bringup.robotfile import EditError, format_number, set_values
from fpgalink.protocol.paramfile import parse_parameter_file
from fpgalink.protocol.robot import SEED_ROBOT_TOML, parse_robot


def test_chi_makes_odometry_agree_with_the_reference() -> None:
    # odometry with χ 1.65 said 380°; the robot really turned 360°: with χ' odometry says
    # 380·1.65/χ' — 360 when χ' = 1.65·380/360
    result = chi_from_turn(1.65, math.radians(380), math.radians(360))
    assert result.after == pytest.approx(1.65 * 380 / 360)
    assert result.error_before == pytest.approx(20 / 360)
    clockwise = chi_from_turn(1.65, math.radians(-380), math.radians(-360))
    assert clockwise.after == pytest.approx(result.after)


def test_the_radius_makes_odometry_agree_with_the_reference() -> None:
    result = radius_from_run(0.20, 1.9, 2.0)
    assert result.after == pytest.approx(0.20 * 2.0 / 1.9)
    assert radius_from_run(0.2, -1.9, -2.0).after == pytest.approx(result.after)


@pytest.mark.parametrize(("call", "message"), [
    (lambda: chi_from_turn(1.6, 1.0, 0.5), "at least 90°"),
    (lambda: chi_from_turn(1.6, 3.0, -3.0), "opposite ways"),
    (lambda: chi_from_turn(1.6, 3.0, 30.0), "outside 1..10"),
    (lambda: chi_from_turn(1.6, math.nan, 3.0), "not a number"),
    (lambda: radius_from_run(0.2, 0.1, 0.2), "at least 0.5 m"),
    (lambda: radius_from_run(0.2, 2.0, -2.0), "opposite ways"),
    (lambda: radius_from_run(0.2, 0.001, 100.0), "outside"),
])
def test_runs_that_cannot_calibrate_are_refused(call: object, message: str) -> None:
    with pytest.raises(CalibrationError, match=message):
        call()  # type: ignore[operator]


def test_a_gyros_bias_is_taken_out_before_its_rate_is_integrated() -> None:
    bias = math.radians(0.5)
    gyro = GyroHeading.from_samples(
        [bias + 0.001 * (-1) ** k for k in range(100)],  # standing still
        [(0.02 * k, math.radians(20) + bias) for k in range(501)])  # 10 s at 20 deg/s
    assert gyro.bias == pytest.approx(bias)
    assert math.degrees(gyro.heading) == pytest.approx(200.0, rel=1e-9)
    gyro.turning(math.nan, 1.0)  # a broken sample is skipped
    assert gyro.samples == 501


def test_headings_unwrap_through_pi() -> None:
    angles = [math.remainder(math.radians(d), math.tau) for d in range(0, 725, 5)]
    assert unwrapped_change(angles) == pytest.approx(math.radians(720))
    assert unwrapped_change(reversed(angles)) == pytest.approx(-math.radians(720))
    assert unwrapped_change([0.1, math.nan, 0.3]) == pytest.approx(0.2)


def test_a_robot_file_is_edited_in_place() -> None:
    text = set_values(SEED_ROBOT_TOML, {("surfaces", "gravel"): 1.7123,
                                        ("", "wheel_radius"): 0.2043,
                                        ("surfaces", "sand"): 2.1,
                                        ("board_parameters.L.A", "Kp_Wheel_Pid"): 612.25},
                      "robot.toml")
    robot = parse_robot(text, "robot.toml")
    assert robot.surfaces["gravel"] == 1.7123 and robot.surfaces["sand"] == 2.1
    assert robot.wheel_radius == 0.2043
    assert "gravel = 1.7123" in text
    # the comment after a value, and every other line, kept
    assert "wheel_radius = 0.2043        # m (wheel diameter 0.40 m)" in text
    kept = [line for line in SEED_ROBOT_TOML.splitlines()
            if not line.startswith(("gravel", "wheel_radius"))]
    assert all(line in text.splitlines() for line in kept)
    assert dict((p.name, v) for p, c, v in robot.settings_for("L") if c == 1)[
        "Kp_Wheel_Pid"] == pytest.approx(612.25)


def test_a_parameter_set_is_written_and_edited() -> None:
    text = set_values("# tuned\n", {("A", "Kp_Wheel_Pid"): 640.0, ("A", "Ti_Wheel_Pid"): 0.241,
                                    ("B", "Kp_Wheel_Pid"): 1192.9}, "gains.toml")
    values = {(p.name, c): v for p, c, v in parse_parameter_file(text, "gains.toml")}
    assert values[("Kp_Wheel_Pid", 1)] == pytest.approx(640.0)
    assert values[("Kp_Wheel_Pid", 2)] == pytest.approx(1192.9, rel=1e-6)
    again = set_values(text, {("A", "Kp_Wheel_Pid"): 700.0}, "gains.toml")
    assert again.count("Kp_Wheel_Pid") == 2 and "Kp_Wheel_Pid = 700.0" in again


def test_an_edit_that_cannot_be_made_is_refused() -> None:
    inline = 'name = "x"\nsurfaces = { gravel = 1.6 }\n'
    with pytest.raises(EditError, match="edit it by hand"):
        set_values(inline, {("surfaces", "gravel"): 1.7}, "robot.toml")
    with pytest.raises(EditError):
        format_number(math.inf)
    assert format_number(2.0) == "2.0" and format_number(1e-7) == "1e-07"
