"""The command arbiter, sans-I/O: what each kind of command sends, a ramp under the
acceleration limits stepped on the boards' clock, a timed command running out, the held
command and its window, the enable's renewal; checked against the seed robot's
kinematics."""

from __future__ import annotations

import itertools
import math

import pytest

from fpgalink.protocol import LocalProtocolError
from fpgalink.protocol.robot import seed_robot
from fpgalink.robot.arbiter import MAX_CONTROL_STEP_S, CommandArbiter, Source
from fpgalink.robot.drive import wheel_command
from fpgalink.robot.limits import AxisLimits

ROBOT = seed_robot().on_surface("ideal")


def arbiter(max_acceleration: float = math.nan) -> CommandArbiter:
    arb = CommandArbiter(ROBOT)
    arb.set_limits(AxisLimits(max_velocity=0.25, max_acceleration=max_acceleration),
                   AxisLimits(max_velocity=ROBOT.max_angular_speed_rad),
                   (ROBOT.max_linear_speed, ROBOT.max_angular_speed_rad))
    return arb


def test_a_body_command_is_the_wheel_command_of_the_robot() -> None:
    arb = arbiter()
    send = arb.drive(0.1, 0.2)
    expected = wheel_command(ROBOT, 0.1, 0.2)
    assert send.references == expected.references and send.command == expected
    assert arb.source is Source.DRIVE and arb.command == expected
    with pytest.raises(LocalProtocolError):
        arb.drive(math.nan, 0.0)


def test_wheel_references_by_name_forward_positive_the_others_zero() -> None:
    description = seed_robot().on_surface("ideal")
    arb = CommandArbiter(description)
    send = arb.wheels({"FL": 30.0, "BR": -10.0})
    fl, br = description.wheel("FL"), description.wheel("BR")
    assert send.references[fl.board][fl.channel - 1] == 30.0 * fl.forward
    assert send.references[br.board][br.channel - 1] == -10.0 * br.forward
    assert sum(1 for refs in send.references.values() for r in refs if r != 0.0) == 2
    assert send.command is None and arb.command is None and arb.source is Source.WHEELS
    for bad in ({"XX": 1.0}, {"FL": math.inf}):
        with pytest.raises(LocalProtocolError):
            arb.wheels(bad)


def test_the_speed_limit_scales_every_body_command_keeping_its_curvature() -> None:
    arb = CommandArbiter(ROBOT)
    arb.set_limits(AxisLimits(max_velocity=0.1), AxisLimits(max_velocity=1.0),
                   (ROBOT.max_linear_speed, ROBOT.max_angular_speed_rad))
    command = arb.drive(0.2, 0.1).command
    assert command is not None
    assert command.v == pytest.approx(0.1) and command.omega == pytest.approx(0.05)
    assert arb.description.max_linear_speed == 0.1


def test_without_rate_limits_a_velocity_command_is_driven_at_once() -> None:
    arb = arbiter()
    send = arb.velocity(0.1, 0.0, (0.0, 0.0))
    assert send is not None and send.command is not None and send.command.v == 0.1
    assert not arb.ramping


def test_with_an_acceleration_limit_a_step_is_a_ramp_on_the_boards_clock() -> None:
    arb = arbiter(max_acceleration=0.2)
    arb.control_period = 0.01
    assert arb.velocity(0.1, 0.0, (0.0, 0.0)) is None and arb.ramping
    driven = []
    t_us = 1_000_000
    assert arb.control_step(t_us) is None  # the first step only sets the clock
    while t_us < 2_000_000:  # a second: a sample a millisecond, a step every tenth
        t_us += 1000
        send = arb.control_step(t_us)
        if send is not None:
            assert send.command is not None
            driven.append((t_us, send.command.v))
    assert arb.ramping  # held at the command: what it follows until another comes
    steps = [(b[1] - a[1]) / ((b[0] - a[0]) / 1e6) for a, b in itertools.pairwise(driven)]
    assert driven[-1][1] == pytest.approx(0.1)
    assert len(driven) == pytest.approx(50, abs=2)  # 0.5 s at 0.2 m/s², every 10 ms
    assert max(steps) == pytest.approx(0.2, rel=1e-6)


def test_another_command_or_a_stop_ends_a_ramp_and_the_next_starts_from_there() -> None:
    arb = arbiter(max_acceleration=0.2)
    arb.velocity(0.1, 0.0, (0.0, 0.0))
    arb.control_step(0)
    arb.control_step(50_000)  # 0.05 s: 0.01 m/s
    arb.drive(0.05, 0.0)  # the go-to, say, takes over
    assert not arb.ramping
    arb.velocity(0.1, 0.0, (0.0, 0.0))
    send = arb.control_step(100_000)
    assert send is not None and send.command is not None
    assert send.command.v == pytest.approx(0.05 + 0.2 * 0.05)  # from what it drove
    arb.stopped()  # supervision disabled every board
    assert not arb.ramping and arb.command is None and arb.source is None


def test_after_wheel_references_a_ramp_starts_from_the_measured_speeds() -> None:
    arb = arbiter(max_acceleration=0.2)
    arb.wheels({"FL": 10.0})
    arb.velocity(0.1, 0.0, (0.04, 0.0))
    arb.control_step(0)
    send = arb.control_step(10_000)
    assert send is not None and send.command is not None
    assert send.command.v == pytest.approx(0.04 + 0.2 * 0.01)


def test_a_stalled_host_makes_at_most_a_tenth_of_a_second_one_step() -> None:
    arb = arbiter(max_acceleration=0.2)
    arb.velocity(0.1, 0.0, (0.0, 0.0))
    arb.control_step(0)
    send = arb.control_step(3_000_000)  # 3 s of board time later
    assert send is not None and send.command is not None
    assert send.command.v == pytest.approx(0.2 * MAX_CONTROL_STEP_S)


def test_a_timed_command_running_out_brings_the_wheels_to_rest() -> None:
    arb = arbiter()
    arb.command_timeout = 0.5
    arb.drive(0.1, 0.0, Source.VELOCITY)
    arb.timed(10.0, zero=False)
    assert arb.get_timer() == pytest.approx(10.5)
    assert arb.handle_timer(10.4, enabled=True) == (False, None, None)
    _renew, notice, send = arb.handle_timer(10.5, enabled=True)
    assert notice is not None and "no command for 0.5 s" in notice.text
    assert send is not None and all(refs == (0.0, 0.0) for refs in send.references.values())
    assert arb.get_timer() is None  # said once
    # A zero command needs no timeout; one another source took over neither.
    arb.timed(11.0, zero=True)
    assert arb.get_timer() is None
    arb.timed(12.0, zero=False)
    arb.drive(0.1, 0.0, Source.GOAL)
    assert arb.get_timer() is None


def test_a_timed_out_ramp_brakes_within_the_limits() -> None:
    arb = arbiter(max_acceleration=0.2)
    arb.command_timeout = 0.5
    arb.velocity(0.1, 0.0, (0.0, 0.0))
    arb.timed(0.0, zero=False)
    _, notice, send = arb.handle_timer(0.5, enabled=True)
    assert notice is not None and send is None and arb.ramping  # towards (0, 0)


def test_a_held_command_is_given_back_within_its_window_once() -> None:
    arb = arbiter()
    arb.command_timeout = 0.5
    arb.hold(Source.VELOCITY, (0.2, 0.0), 1.0)
    held = arb.take_held(1.4)
    assert held is not None and held.value == (0.2, 0.0)
    assert arb.take_held(1.4) is None
    arb.hold(Source.VELOCITY, (0.2, 0.0), 1.0)
    assert arb.take_held(1.6) is None  # too old: never sent


def test_the_enable_is_renewed_on_its_period_while_enabled() -> None:
    arb = arbiter()
    assert arb.get_timer() is None
    arb.renew_period = 0.125
    arb.enabled(2.0)
    assert arb.get_timer() == pytest.approx(2.125)
    assert arb.handle_timer(2.125, enabled=True)[0] is True
    arb.enabled(2.125)
    assert arb.handle_timer(2.25, enabled=False)[0] is False  # stopped meanwhile: not renewed
