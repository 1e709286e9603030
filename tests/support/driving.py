"""Driving a robot in a test the way a teleop's deadman does: references every 20 ms, the
enable renewed, and enabled again when a fault stopped the robot and it is ready once more.
On a loaded machine the robot may stop for a fault of the test's own making (a stalled
test process lapses the boards' watchdog): a test that is about something else drives on
through it, and a test about a fault looks for that fault among the robot's events."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from fpgalink.robot import Robot, RobotStopped
from fpgalink.robot.supervision import State
from tests.support.served import PATIENCE

__all__ = ["drive_until"]


async def drive_until(robot: Robot, done: Callable[[], object], what: str, v: float = 0.15,
                      omega: float = 0.0, timeout: float = 3 * PATIENCE) -> None:
    loop = asyncio.get_running_loop()
    give_up = loop.time() + timeout
    while not done():
        if loop.time() > give_up:
            raise TimeoutError(f"timed out after {timeout:g} s driving until {what}")
        if robot.state is not State.ENABLED:
            try:
                robot.enable()
            except RobotStopped:  # not ready yet (reconfiguring, stale): try again soon
                await asyncio.sleep(0.02)
                continue
        robot.drive(v, omega)
        robot.enable()  # the deadman
        await asyncio.sleep(0.02)
