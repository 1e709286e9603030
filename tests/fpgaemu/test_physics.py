"""The physics body (fpgaemu.physics on MuJoCo): the motor as a torque source still answers
its duty as the seed's identified model in the air; a still robot's physics sleeps and its
boards idle; the IMU feels gravity; the worm gears hold an unpowered robot on the slope;
options are checked."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import pytest

from fpgaemu import physics
from fpgaemu.motor import (
    GEARS,
    MAX_DUTY,
    MotorConstants,
    WheelDrive,
    drive_train,
    identified_response,
)
from fpgaemu.robot import EmulatedRobot, robot_from_options
from fpgaemu.timeline import CLOCK_HZ, ms
from fpgalink.protocol.robot import Pose, seed_robot
from tests.support.seedtable import Run

pytestmark = pytest.mark.skipif(not physics.available(), reason=physics.why_unavailable()
                                or "")

HIGH_DC = sum(GEARS["high"][0]) / (1 + sum(GEARS["high"][1]))


def lifted(gear: str, step_ms: int = 2) -> tuple[physics.PhysicsBody, dict[str, WheelDrive]]:
    """The robot on the test bench: chassis held in the air, wheels free."""
    description = seed_robot()
    train = drive_train(gear)
    drives = {w.name: WheelDrive(train) for w in description.wheels}
    body = physics.PhysicsBody(description, drives, {w.name: 1 for w in description.wheels},
                               lifted=True, step_cycles=ms(step_ms))
    return body, drives


def air_step_response(gear: str, duty: float, samples: int = 60) -> list[float]:
    """Wheel FL's speed (deg/s) every 50 ms after a duty step, the windings integrated as
    a board integrates them."""
    body, drives = lifted(gear)
    for drive in drives.values():
        drive.duty = round(MAX_DUTY * duty)
    speeds, cycle = [], 0
    for _ in range(samples):
        speeds.append(drives["FL"].speed_dps)
        for _ in range(25):  # 25 steps of 2 ms
            body.advance(cycle + body.step_cycles)
            for drive in drives.values():
                drive.hold_current(body.step_cycles)
            cycle += body.step_cycles
    return speeds


@pytest.mark.parametrize("gear", ["high", "low"])
def test_in_the_air_the_driven_wheel_matches_the_identified_model(gear: str) -> None:
    seed = [90.0 / HIGH_DC * y for y in identified_response(gear, [0.5] * 60)]
    ours = air_step_response(gear, 0.5)
    full = abs(seed[-1])
    worst = max(abs(a - b) for a, b in zip(ours, seed, strict=True)) / full
    assert worst < 0.01, f"{gear}: worst {worst:.2%} of the final speed"


def test_the_drive_train_keeps_the_plants_gains() -> None:
    high, low = drive_train("high"), drive_train("low")
    motor = MotorConstants()
    assert high.stall_torque_nm == pytest.approx(motor.stall_torque_wheel_nm)
    # The low gear is a reduction 0.349 times as fast: about 950 N·m (seed §3.1: 1,000).
    assert low.stall_torque_nm == pytest.approx(high.stall_torque_nm / 0.3487, rel=0.01)
    for train in (high, low):
        assert min(train.rotor_inertia, train.wheel_inertia, train.stiffness,
                   train.damping, train.rotor_friction) > 0
    full = air_step_response("high", 1.0, 80)
    assert full[-1] == pytest.approx(90.0, rel=2e-3)
    assert air_step_response("low", 1.0, 80)[-1] == pytest.approx(31.38, rel=2e-3)


def test_a_still_robot_costs_nothing_and_sleeps_again_after_a_drive() -> None:
    run = Run.make("gravel", "mujoco")
    robot = run.robot
    assert robot.physics is not None
    run.hold_wheels(None, None)  # the boards never enabled
    run.run(5.0)
    assert robot.physics.asleep and robot.physics.steps == 0
    assert all(board.quiescent for board in robot.boards.values())
    run.hold_wheels(40.0, 40.0)
    run.run(2.0)
    assert not robot.physics.asleep and robot.truth().pose.x > 0.2
    run.hold_wheels(None, None)  # no more RE: the boards' watchdogs disable them
    run.run(5.0)
    assert robot.physics.asleep
    assert all(board.quiescent for board in robot.boards.values())
    steps = robot.physics.steps
    rest = robot.truth().pose
    run.run(30.0)
    assert robot.physics.steps == steps and robot.truth().pose == rest


def test_the_imu_feels_gravity_level_and_on_the_slope() -> None:
    level = EmulatedRobot(body="mujoco", surface="marble").truth()
    assert level.imu is not None
    ax, ay, az = level.imu.linear_acceleration
    assert az == pytest.approx(9.81, abs=0.3) and abs(ax) < 0.3 and abs(ay) < 0.3
    assert all(abs(w) < math.radians(2) for w in level.imu.angular_velocity)
    slope = EmulatedRobot(body="mujoco", surface="slope45-sand").truth()
    assert slope.pitch == pytest.approx(-math.pi / 4, abs=0.02)  # nose up
    ax, _, az = slope.imu.linear_acceleration
    g45 = 9.81 * math.sqrt(0.5)
    assert ax == pytest.approx(g45, abs=0.3) and az == pytest.approx(g45, abs=0.3)


def test_an_unpowered_robot_is_held_on_the_slope_by_its_worm_gears() -> None:
    robot = EmulatedRobot(body="mujoco", surface="slope45-sand")
    start = robot.truth().pose
    robot.run_for(5.0)
    end = robot.truth().pose
    assert math.hypot(end.x - start.x, end.y - start.y) < 1e-3
    assert robot.physics is not None and robot.physics.asleep


def test_the_truth_record_carries_the_imu_and_attitude() -> None:
    record = EmulatedRobot(body="mujoco").truth().record()
    assert record["body"] == "mujoco" and record["surface"] == "gravel"
    assert {"z", "roll", "pitch", "imu"} <= set(record)
    assert set(record["imu"]) == {"t", "angular_velocity", "linear_acceleration",
                                  "orientation", "angular_velocity_variance",
                                  "linear_acceleration_variance"}
    kinematic = EmulatedRobot(body="kinematic").truth().record()
    assert kinematic["body"] == "kinematic" and "imu" not in kinematic


def test_the_robot_can_be_placed() -> None:
    robot = EmulatedRobot(body="mujoco")
    assert robot.physics is not None
    robot.physics.place(Pose(1.0, -2.0, 2.0))
    pose = robot.truth().pose
    assert (pose.x, pose.y, pose.theta) == pytest.approx((1.0, -2.0, 2.0), abs=1e-3)


@pytest.mark.parametrize(("options", "message"), [
    ({"body": ["ode"]}, "body 'ode': choose mujoco or kinematic"),
    ({"body": ["mujoco"], "surface": ["ideal"]}, "the mujoco body knows gravel"),
    ({"body": ["kinematic"], "surface": ["stairs"]}, "it is flat"),
    ({"surface": ["ice"]}, "surface 'ice'"),
    ({"uart_rx": ["fast"]}, "uart_rx must be edge or level"),
    ({"tx_gap": ["-1"]}, "tx_gap must be a whole number"),
])
def test_bad_robot_options_are_one_clear_line(options: dict[str, list[str]],
                                              message: str) -> None:
    with pytest.raises(ValueError, match=message) as caught:
        robot_from_options(options, 1_000_000)
    assert "\n" not in str(caught.value)


def test_the_default_body_is_mujoco_except_on_a_kinematic_only_surface() -> None:
    assert robot_from_options({}, 1_000_000).body_kind == "mujoco"
    assert robot_from_options({"surface": ["ideal"]}, 1_000_000).body_kind == "kinematic"
    assert robot_from_options({"surface": ["stairs"]}, 1_000_000).body_kind == "mujoco"


def test_the_physics_step_is_a_whole_number_of_board_periods() -> None:
    assert physics.STEP_CYCLES % ms(1) == 0
    with pytest.raises(ValueError, match="whole number of milliseconds"):
        EmulatedRobot(body="mujoco", physics_step_cycles=ms(1) + 1)
    robot = EmulatedRobot(body="mujoco")
    assert robot.physics is not None
    assert robot.physics.model.opt.timestep == pytest.approx(physics.STEP_CYCLES / CLOCK_HZ)


@pytest.mark.parametrize("surface", ["gravel", "marble"])
def test_go_to_arrives_on_the_physics_body(surface: str) -> None:
    """Algorithm 1 (fpgalink.robot.goto) on odometry, the body slipping under it: the
    controller arrives, and the body is really there, within what odometry lost."""
    from tests.support.emulated import RobotSim

    sim = RobotSim.make(surface, body="mujoco")
    controller = sim.go_to(1.0, 0.5, limit_s=40.0)
    assert controller.done
    odometry, truth = sim.odometry.pose, sim.truth
    assert math.hypot(odometry.x - 1.0, odometry.y - 0.5) < 0.06  # the controller's Tr
    error = math.hypot(truth.x - odometry.x, truth.y - odometry.y)
    assert math.hypot(truth.x - 1.0, truth.y - 0.5) < 0.15
    # On this body odometry is not the truth (it is on the kinematic one).
    assert error > 0.005
    # and back, behind the robot: odometry's error grows with the way (the turns on
    # gravel cost it most), the body ends within a few percent of it from the goal
    controller = sim.go_to(0.0, 0.0, limit_s=40.0)
    assert controller.done
    travelled = sim.robot.truth().distance
    assert travelled > 2.0
    assert math.hypot(sim.truth.x, sim.truth.y) < 0.15 * travelled


def test_the_body_renders_headless_where_an_opengl_is_there() -> None:
    """fpgaemu.physics.render with Mesa's software EGL (no display, no GPU): a picture
    that is not blank. Skipped where the machine has no EGL."""
    program = ("from fpgaemu.physics import render\n"
               "from fpgaemu.robot import EmulatedRobot\n"
               "image = render(EmulatedRobot(body='mujoco').physics, 64, 48)\n"
               "print(image.shape, float(image.std()))\n")
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True,
                          timeout=60, env={**os.environ, "MUJOCO_GL": "egl"})
    if done.returncode != 0 and ("EGL" in done.stderr or "GL" in done.stderr):
        pytest.skip(f"no headless OpenGL here: {done.stderr.strip().splitlines()[-1]}")
    assert done.returncode == 0, done.stderr
    shape, spread = done.stdout.split(")")
    assert shape == "(48, 64, 3" and float(spread) > 5.0  # something drawn, not one colour


def test_a_stuck_wheel_is_held_and_the_robot_drags_it() -> None:
    """The wheel-stuck fault on the physics body: the wheel's joint held, its loop winds up
    to full duty and 24 A (V/R, as on the kinematic body), the others drive on and the
    body turns towards the stuck wheel."""
    run = Run.make("gravel", "mujoco", faults={"L": ["wheel-stuck=A"]})
    run.hold_wheels(40.0, 40.0)
    run.run(3.0)
    assert run.robot.physics is not None
    speeds = run.robot.physics.wheel_speeds()
    assert abs(speeds["FL"]) < 0.1 and speeds["BL"] == pytest.approx(40.0, rel=0.02)
    assert run.pwm()["FL"] == MAX_DUTY
    firmware = run.robot.boards["L"].peripherals["firmware"]
    assert firmware.channels[1].current == pytest.approx(24.0, rel=0.02)  # type: ignore[attr-defined]
    truth = run.robot.truth()
    assert truth.pose.x > 0.2 and truth.pose.theta > 0.01  # left side slower: turns left
