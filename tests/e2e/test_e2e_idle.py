"""A served board at rest costs nothing, fresh or after use: ``fpgaemu serve`` and
``serve --robot`` go back to a fresh server's CPU use once the motion they were driven
through has ended (the wheels come to rest in static friction's dead band, and the
quiescent board is no longer woken for its timer ticks).

What is measured is CPU time the server's process consumed over a window (from
``/proc/PID/stat``), compared with the same server's own use when fresh, in the same run:
an idle process's consumption does not grow when the machine is busy, so the comparison
holds under load. How long the return to idle takes is not asserted in wall-clock time
(a loaded machine may delay it); it is bounded in emulated time by
``tests/fpgaemu/test_motor.py``."""

from __future__ import annotations

import asyncio
import os
import sys

import pytest

from fpgalink import open_link
from fpgalink.protocol.robot import seed_robot
from fpgalink.robot import Robot
from tests.support.driving import drive_until
from tests.support.served import PATIENCE, wait_until
from tests.support.serving import Served, serve

pytestmark = [pytest.mark.timeout(120),
              pytest.mark.skipif(not sys.platform.startswith("linux"),
                                 reason="reads /proc/PID/stat")]

TICKS = os.sysconf("SC_CLK_TCK")
#: Long enough that 1 % of a core is several clock ticks of CPU time.
WINDOW_S = 3.0
#: How long a used server may take to be idle again before the test gives up (generous: on
#: an idle machine it is about 3 s of emulated decay).
SETTLE_LIMIT_S = 60.0


def cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS  # utime, stime


async def cpu_share(server: Served) -> float:
    """The share of one core the server used over one window."""
    loop = asyncio.get_running_loop()
    cpu0, t0 = cpu_seconds(server.proc.pid), loop.time()
    await asyncio.sleep(WINDOW_S)  # the measurement window itself, not a wait for a condition
    return (cpu_seconds(server.proc.pid) - cpu0) / (loop.time() - t0)


async def back_to_idle(server: Served, fresh: float) -> None:
    """Measure window after window until one is within a fresh server's use (3× its share,
    or 1 % of a core, whichever is higher, plus one clock tick); fail if none is within
    :data:`SETTLE_LIMIT_S`."""
    bound = max(3 * fresh, 0.01) + 1 / TICKS / WINDOW_S
    shares: list[float] = []
    loop = asyncio.get_running_loop()
    give_up = loop.time() + SETTLE_LIMIT_S
    while loop.time() < give_up:
        shares.append(await cpu_share(server))
        if shares[-1] <= bound:
            return
    raise AssertionError(f"served board never idle again: shares {shares}, fresh {fresh}, "
                         f"bound {bound}")


async def test_a_served_board_is_idle_again_after_a_step() -> None:
    async with serve("--pty") as server:
        fresh = await cpu_share(server)
        async with open_link(server.url) as link:
            link.enable()
            await link.set_param("GetDataPeriodical", 1)
            link.set_references(60.0, -45.0)
            await wait_until(lambda: link.latest is not None and link.latest.a.speed > 30,
                             PATIENCE, "channel A turning")
            link.disable()
            await link.set_param("GetDataPeriodical", 0)
        await back_to_idle(server, fresh)


async def test_a_served_robot_is_idle_again_after_a_drive() -> None:
    async with serve("--robot", "--pty") as server:
        fresh = await cpu_share(server)
        async with Robot.open(seed_robot(), server.ready) as robot:
            await drive_until(robot, lambda: robot.pose.x > 0.05, "the robot moving", 0.2,
                              0.1)
            robot.disable()
        await back_to_idle(server, fresh)
