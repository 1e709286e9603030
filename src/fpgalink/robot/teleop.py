"""A teleop's commands (ROS's ``cmd_vel`` and ``wheel_refs``): through the robot's command
arbiter, each one timed (:attr:`~fpgalink.robot.arbiter.CommandArbiter.command_timeout`),
held while the robot is not enabled (its enable, on a topic of its own, may come just after
it) and sent when it is enabled in time, and — without a deadman
(:attr:`~fpgalink.robot.arbiter.CommandArbiter.auto_enable`) — the request to enable it."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

from fpgalink.errors import FpgalinkError
from fpgalink.robot.arbiter import Commanded, CommandNotice, Source, Taken
from fpgalink.robot.errors import RobotError, RobotStopped
from fpgalink.robot.supervision import State

if TYPE_CHECKING:
    from fpgalink.robot.robot import Robot

__all__ = ["Teleop"]

Value = tuple[float, float] | Mapping[str, float]


class Teleop:
    """``robot.teleop``: see the module docstring. ``now`` is the robot's loop's clock;
    ``rearm`` re-arms the arbiter's timer after a timed command."""

    def __init__(self, robot: Robot, now: Callable[[], float], rearm: Callable[[], None]
                 ) -> None:
        self.robot = robot
        self._now, self._rearm = now, rearm

    def velocity(self, v: float, omega: float) -> Commanded:
        """A velocity command: through the limits (a ramp under acceleration limits).
        Non-finite values raise :class:`~fpgalink.robot.RobotError`."""
        if not (math.isfinite(v) and math.isfinite(omega)):
            raise RobotError(f"a velocity command must be finite, got ({v}, {omega})")
        return self._command(Source.VELOCITY, (v, omega))

    def wheels(self, references: Mapping[str, float]) -> Commanded:
        """Wheel references by name, as :meth:`~fpgalink.robot.Robot.set_wheel_references`
        takes them (an unknown wheel or a non-finite value raises)."""
        self.robot.arbiter.check_wheels(references)
        return self._command(Source.WHEELS, dict(references))

    def _command(self, source: Source, value: Value) -> Commanded:
        robot = self.robot
        now = self._now()
        if robot.arbiter.auto_enable and robot.state is not State.ENABLED:
            try:  # without the deadman a command is the request to drive
                robot.enable()
            except RobotStopped as exc:
                return Commanded(Taken.REFUSED, reason=str(exc))
        if robot.state is not State.ENABLED:
            robot.arbiter.hold(source, value, now)
            stop = robot.last_stop
            return Commanded(Taken.HELD, reason="the robot is not enabled" + (
                f" ({stop.describe()})" if stop else ""))
        robot.arbiter.held = None
        return self._execute(source, value, now)

    def _execute(self, source: Source, value: Value, now: float) -> Commanded:
        robot = self.robot
        if isinstance(value, tuple):
            odometry = robot.odometry
            send = robot.arbiter.velocity(*value, (odometry.v, odometry.omega))
            zero = value == (0.0, 0.0)
        else:
            send = robot.arbiter.wheels(value)
            zero = all(v == 0.0 for v in value.values())
        if send is not None:
            robot.send(send)
        robot.arbiter.timed(now, zero)
        self._rearm()
        if send is None:
            return Commanded(Taken.RAMPING)
        return Commanded(Taken.DRIVEN, send.command)

    def release(self, now: float) -> CommandNotice | None:
        """The robot was just enabled: the held command, if still fresh, is driven now,
        and said (what could not be sent too)."""
        held = self.robot.arbiter.take_held(now)
        if held is None:
            return None
        try:
            done = self._execute(held.source, held.value, now)
        except FpgalinkError as exc:  # the enable stands; the command is said lost
            return CommandNotice(now, f"held command not sent: {exc}")
        return CommandNotice(now, "held command sent", done.command, fault=False)
