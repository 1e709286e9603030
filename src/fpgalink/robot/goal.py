"""Driving to a goal with the seed's position controller (:mod:`.goto`) on a started robot,
over asyncio: :meth:`fpgalink.robot.Robot.go_to`. Its commands go through the robot's
arbiter as the go-to's own (a velocity command's timeout does not cut them short)."""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from fpgalink.protocol.robot import Pose
from fpgalink.robot.arbiter import Source
from fpgalink.robot.errors import GoalTimeout, RobotStopped
from fpgalink.robot.goto import GoTo, GoToCommand, GoToSettings
from fpgalink.robot.supervision import State

if TYPE_CHECKING:
    from fpgalink.robot.robot import Robot

__all__ = ["SETTLED_SPEED", "SETTLED_TURN", "go_to"]

#: Below these the robot counts as at rest (m/s, rad/s).
SETTLED_SPEED = 0.005
SETTLED_TURN = math.radians(0.5)


async def go_to(robot: Robot, x: float, y: float, theta: float | None, timeout: float,
                settings: GoToSettings, on_step: Callable[[GoToCommand], None] | None
                ) -> Pose:
    """See :meth:`fpgalink.robot.Robot.go_to`."""
    if not (math.isfinite(timeout) and timeout > 0):
        raise ValueError(f"timeout must be a positive number of seconds, got {timeout!r}")
    controller = GoTo(x, y, theta, settings)
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    robot.stopped.clear()
    try:
        while True:
            if robot.state is not State.ENABLED:
                stop = robot.last_stop
                raise RobotStopped("go_to stopped: " + (
                    stop.describe() if stop else "the robot is not enabled"), stop)
            step = controller.step(robot.odometry.pose, loop.time())
            if on_step is not None:
                on_step(step)
            if controller.done:
                robot.stop()
                if await _settled(robot, deadline) and controller.arrived(robot.odometry.pose):
                    return robot.odometry.pose
                # It rolled out of the tolerance while stopping: go on from here.
                controller = GoTo(x, y, theta, controller.settings)
                continue
            if loop.time() > deadline:
                robot.stop()
                raise GoalTimeout(
                    f"not at ({x:g}, {y:g}) after {timeout:g} s: {step.distance:.2f} m "
                    f"away, {math.degrees(step.heading_error):.0f}° off, phase "
                    f"{step.phase.value}")
            robot.send(robot.arbiter.drive(step.v, step.omega, Source.GOAL))
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(robot.stopped.wait(), robot.control_period)
    except BaseException:
        if robot.state is State.ENABLED:
            robot.stop()
        raise


async def _settled(robot: Robot, deadline: float) -> bool:
    """Wait until the wheels have stopped (or ``deadline``): an arrival counts at rest."""
    loop = asyncio.get_running_loop()
    odometry = robot.odometry
    while loop.time() < deadline:
        if abs(odometry.v) < SETTLED_SPEED and abs(odometry.omega) < SETTLED_TURN:
            return True
        if robot.state is not State.ENABLED:
            return False
        await asyncio.sleep(robot.control_period)
    return False
