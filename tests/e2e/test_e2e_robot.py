"""The robot across real processes: ``fpgaemu serve --robot`` (two boards, one body, a truth
endpoint) driven over its ptys, and supervision when one board's serving process is
killed."""

from __future__ import annotations

import asyncio
import json
import math
import signal
from pathlib import Path

import pytest

from fpgalink.events import StatusEvent
from fpgalink.protocol.robot import seed_robot
from fpgalink.robot import Robot
from fpgalink.robot.supervision import State, StopReason
from tests.support.driving import drive_until
from tests.support.served import PATIENCE, wait_until
from tests.support.serving import serve

pytestmark = pytest.mark.timeout(60)


async def test_a_served_robot_moves_its_body_and_streams_the_truth() -> None:
    async with serve("--robot", "--pty", "--surface", "ideal") as server:
        url = server.truth
        assert url is not None and url.startswith("socket://127.0.0.1:")
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        reader, writer = await asyncio.open_connection(host, int(port))
        try:
            first = json.loads(await reader.readline())
            assert {"t", "x", "y", "theta", "v", "omega", "surface"} <= set(first)
            assert first["surface"] == "ideal"
            robot = Robot.open(seed_robot().on_surface("ideal"), server.ready)
            async with robot:
                await drive_until(robot, lambda: robot.pose.x > 0.2, "odometry at 0.2 m",
                                  v=0.2)
                robot.disable()

                # The body really moved; once it rests, odometry agrees with it.
                async def at_rest() -> dict[str, float]:
                    previous: dict[str, float] | None = None
                    while True:
                        line: dict[str, float] = json.loads(await reader.readline())
                        if previous is not None and line["x"] > 0.2 \
                                and line["x"] == previous["x"]:
                            return line
                        previous = line

                latest = await asyncio.wait_for(at_rest(), PATIENCE)
                await wait_until(lambda: abs(robot.odometry_state.v) < 1e-3, PATIENCE,
                                 "odometry at rest")
                assert latest["t"] > first["t"]
                assert robot.pose.x == pytest.approx(latest["x"], abs=0.02)
        finally:
            writer.close()


async def test_killing_one_boards_server_stops_the_other_board_at_once(tmp_path: Path) -> None:
    # L through serve's --link, removed before the kill (a device's name goes with it, as
    # udev's by-id link does): L's link retries its path, and the killed serve's pty number
    # may be given to another test's board meanwhile.
    board_l = tmp_path / "L"
    async with serve("--pty", "--link", str(board_l)) as left, serve("--pty") as right:
        robot = Robot.open(seed_robot(), {"L": str(board_l), "R": right.url})
        async with robot:
            noticed: list[StatusEvent] = []
            robot.links["L"].on_event(noticed.append)
            events = robot.events()
            robot.enable()
            robot.drive(0.1, 0.0)
            r_link = robot.links["R"]
            await wait_until(lambda: r_link.latest is not None and r_link.latest.a.flags & 1,
                             PATIENCE, "R enabled (TM flags)")
            board_l.unlink()
            left.send_signal(signal.SIGKILL)
            async for event in events:
                if event.state is State.DISABLED:
                    break
            assert event.reason is StopReason.BOARD_LOST and event.board == "L"
            # The stop happened in the very callback that noticed L had gone.
            assert noticed and event.at - noticed[0].at <= 0.05
            # R really got the RD: its own telemetry says disabled, PWM 0.
            await wait_until(lambda: r_link.latest is not None
                             and not r_link.latest.a.flags & 1
                             and r_link.latest.a.pwm == 0 and r_link.latest.b.pwm == 0,
                             PATIENCE, "R disabled with PWM 0")
            assert robot.state is State.DISABLED
            assert math.isfinite(robot.pose.x)
