"""The robot's real life across real processes: ``fpgaemu serve --robot`` with faults on
demand, driven by the library and by ``fpgalink-cli``. A board that restarts mid-drive, a
host frozen past the boards' watchdog, one board's telemetry stopping: each stops the robot
and says why; a restarted board is reconfigured before the robot may drive again.

What is asserted holds on a busy machine: the stop is made in the very callback that
noticed the fault (the same loop time), board facts are read from the emulator's truth
stream (cycle-exact), and nothing waits on a wall-clock figure. A loaded machine may add
faults of its own (a stalled test process lapses the watchdog too): the checks look for
the fault under test among the robot's events, and re-enable after another one."""

from __future__ import annotations

import asyncio
import itertools
import json
import math
import os
import signal
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import pytest

from fpgalink.events import BoardRestarted, RestartEvidence, StatusEvent, TelemetryStale
from fpgalink.protocol.robot import seed_robot
from fpgalink.robot import Robot, RobotStopped
from fpgalink.robot.health import Level
from fpgalink.robot.supervision import State, StopReason, SupervisionEvent
from tests.support.cli import CLI
from tests.support.driving import drive_until
from tests.support.served import PATIENCE, wait_until
from tests.support.serving import Served, serve

pytestmark = pytest.mark.timeout(120)

#: The seed robot never drove faster than this in these tests (m/s).
TOP_SPEED = 0.5


class Truth:
    """The served robot's truth endpoint: the newest record, kept current by a task."""

    def __init__(self) -> None:
        self.latest: dict[str, Any] = {}
        self.records = 0

    @asynccontextmanager
    async def reading(self, url: str) -> AsyncIterator[Truth]:
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        reader, writer = await asyncio.open_connection(host, int(port))

        async def read() -> None:
            while line := await reader.readline():
                self.latest = json.loads(line)
                self.records += 1

        task = asyncio.ensure_future(read())
        try:
            await wait_until(lambda: self.records > 0, PATIENCE, "the truth stream")
            yield self
        finally:
            task.cancel()
            writer.close()

    def board(self, name: str) -> dict[str, Any]:
        board: dict[str, Any] = self.latest["boards"][name]
        return board


@asynccontextmanager
async def served_robot(*faults: str) -> AsyncIterator[tuple[Served, Truth]]:
    args = ["--robot", "--pty", "--surface", "ideal"]
    for fault in faults:
        args += ["--fault", fault]
    async with serve(*args) as server:
        assert server.truth is not None
        async with Truth().reading(server.truth) as truth:
            yield server, truth


def first(events: list[SupervisionEvent], reason: StopReason, board: str
          ) -> SupervisionEvent:
    return next(e for e in events if e.reason is reason and e.board == board
                and not e.recovered)


async def test_a_board_that_restarts_mid_drive_is_reconfigured_before_the_robot_drives_again(
) -> None:
    async with served_robot("L:restart=4") as (server, truth):
        robot = Robot.open(seed_robot().on_surface("ideal"), server.ready)
        async with robot:
            left = robot.links["L"]
            # A parameter set at run time is held by the link: set again after the restart.
            assert await left.set_param("Kp_Wheel_PidA", 400.0) == 400.0
            link_events: list[StatusEvent] = []
            left.on_event(link_events.append)
            events: list[SupervisionEvent] = []
            statuses: list[str] = []
            sub = robot.events()

            async def collect() -> None:
                async for event in sub:
                    events.append(event)
                    level = next(s for s in robot.health() if s.name == "board L")
                    statuses.append(f"{level.level.name}: {level.message}")

            collector = asyncio.ensure_future(collect())
            # Odometry at each of the boards' sample sets, stamped on their clock: what it
            # moved between two sets is compared with how far the body could have gone in
            # the board time between them (a loaded test process reads them late, or
            # drops some, which is no jump; an encoder reset taken as motion is).
            sets = robot.sample_sets()
            poses: list[tuple[int, float, float]] = []

            async def sample() -> None:
                async for stamped in sets:
                    pose = stamped.odometry.pose
                    poses.append((stamped.odometry_stamp, pose.x, pose.y))

            sampler = asyncio.ensure_future(sample())
            try:
                await drive_until(robot, lambda: any(
                    isinstance(e, BoardRestarted) for e in link_events),
                    "board L restarted")
                restart_event = next(e for e in link_events if isinstance(e, BoardRestarted))
                # Driving again needs L reconfigured: enable is refused until then.
                await drive_until(robot, lambda: any(e.recovered for e in events)
                                  and robot.state is State.ENABLED and robot.pose.x > 0.5,
                                  "driving again after the reconfiguration")
            finally:
                sampler.cancel()
                collector.cancel()
                await asyncio.gather(sampler, collector, return_exceptions=True)

            # Stopped in the very callback that noticed the restart.
            stop = first(events, StopReason.BOARD_RESTARTED, "L")
            assert stop.at == restart_event.at
            assert "reconfiguring" in stop.detail
            assert restart_event.evidence in (RestartEvidence.CONFIG_LOST,
                                              RestartEvidence.COUNTER_RESET)
            # Diagnostics: ERROR while reconfiguring, then OK.
            assert any(s.startswith("ERROR: restarted: reconfiguring") for s in statuses)
            board_l = next(s for s in robot.health() if s.name == "board L")
            assert board_l.level is Level.OK, board_l
            # Every held parameter reads back equal on the board; telemetry flows.
            params = truth.board("L")["params"]
            for name, value in left.held.items():
                assert params[name] == pytest.approx(value), name
            assert params["Kp_Wheel_PidA"] == 400.0 and params["GetDataPeriodical"] == 1
            t_us = left.latest.t_us if left.latest is not None else -1
            await wait_until(lambda: left.latest is not None and left.latest.t_us > t_us,
                             PATIENCE, "telemetry from L")
            # The restart's encoder reset was not taken as motion: odometry never jumped.
            jumps = [math.dist(a[1:], b[1:]) - TOP_SPEED * (b[0] - a[0]) / 1e9
                     for a, b in itertools.pairwise(poses)]
            # The reset taken as motion would jump by L's wheels' travel since the start
            # (tens of cm); under load the restarted board's new stamp mapping alone
            # made 1.2 cm of a pose's interval (tests/ros2's check says the same).
            assert len(poses) > 100 and max(jumps) < 0.05, max(jumps)
            assert robot.odometry.reanchors == 1
            assert truth.board("L")["now_s"] > 4.0


async def test_one_boards_telemetry_stopping_stops_the_robot_until_it_comes_again() -> None:
    async with served_robot("L:tm-loss=3:1") as (server, truth):
        robot = Robot.open(seed_robot().on_surface("ideal"), server.ready)
        async with robot:
            link_events: list[StatusEvent] = []
            robot.links["L"].on_event(link_events.append)
            events: list[SupervisionEvent] = []
            sub = robot.events()

            async def collect() -> None:
                async for event in sub:
                    events.append(event)

            collector = asyncio.ensure_future(collect())
            try:
                await drive_until(robot, lambda: any(
                    type(e) is TelemetryStale and
                    truth.board("L")["now_s"] >= 3.0 for e in link_events), "L's stale")
                stale = next(e for e in reversed(link_events)
                             if type(e) is TelemetryStale)
                # The subscription's task may not have had its turn yet (a loaded machine).
                await wait_until(lambda: any(
                    e.reason is StopReason.TELEMETRY_STALE and e.board == "L"
                    for e in events), PATIENCE, "the robot's stop for L's telemetry")
                stop = first(events, StopReason.TELEMETRY_STALE, "L")
                assert stop.at <= stale.at or any(
                    e.at == stale.at for e in events if e.reason is StopReason.TELEMETRY_STALE)
                board_l = next(s for s in robot.health() if s.name == "board L")
                assert board_l.level is Level.ERROR and "telemetry stopped" in board_l.message
                with pytest.raises(RobotStopped, match="telemetry stopped"):
                    robot.enable()  # refused while it lasts
                # The loss ends at 4 s: telemetry resumes, the board is ready, enable works.
                await drive_until(robot, lambda: robot.state is State.ENABLED
                                  and truth.board("L")["now_s"] > 4.2, "driving after")
                assert any(e.recovered and e.board == "L" for e in events)
                # R got the robot's RD when L's telemetry stopped (board facts, cycle-exact).
                assert truth.board("R")["disabled_by"] in ("RD", "rd", "disable") or \
                    truth.board("R")["disabled_s"] is not None
            finally:
                collector.cancel()
                await asyncio.gather(collector, return_exceptions=True)


def _cli(*args: str) -> list[str]:
    return [*CLI, *args]


async def _run_cli(args: list[str]) -> asyncio.subprocess.Process:
    env = {k: v for k, v in os.environ.items() if not k.startswith("FPGALINK_")}
    env.update(COLUMNS="200", NO_COLOR="1", PYTHONUNBUFFERED="1")
    return await asyncio.create_subprocess_exec(
        *args, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, env=env,
        stdin=asyncio.subprocess.DEVNULL)


async def test_a_frozen_cli_host_stops_the_robot_and_says_why() -> None:
    # SIGSTOP the driving CLI for 0.4 s, past the boards' 300 ms watchdog: both boards
    # disable themselves; on SIGCONT the CLI says why and exits 7, never driving on.
    async with served_robot() as (server, truth):
        ports = [f"--port={name}={url}" for name, url in server.ready.items()]
        proc = await _run_cli(_cli(*ports, "drive", "--v", "0.1", "--for", "60"))
        try:
            await wait_until(lambda: truth.latest.get("v", 0) > 0.05, PATIENCE,
                             "the robot driving")
            proc.send_signal(signal.SIGSTOP)
            stopped_at = truth.latest["t"]
            await wait_until(lambda: truth.latest["t"] >= stopped_at + 0.4, PATIENCE,
                             "0.4 s of emulated time")
            proc.send_signal(signal.SIGCONT)
            _, err = await asyncio.wait_for(proc.communicate(), 3 * PATIENCE)
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
        text = err.decode()
        assert proc.returncode == 7, text
        assert "disabled itself (board" in text and "watchdog" in text, text
        for name in ("L", "R"):
            board = truth.board(name)
            assert not board["enabled"] and board["pwm_a"] == board["pwm_b"] == 0


async def test_the_cli_names_a_restart_mid_drive_and_exits_7() -> None:
    async with served_robot("R:restart=3") as (server, truth):
        ports = [f"--port={name}={url}" for name, url in server.ready.items()]
        proc = await _run_cli(_cli(*ports, "drive", "--v", "0.1", "--for", "60"))
        try:
            _, err = await asyncio.wait_for(proc.communicate(), 3 * PATIENCE)
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
        text = err.decode()
        assert proc.returncode == 7, text
        # The first fault it met: R's restart (or, on a loaded machine, one of its own).
        assert "the robot was stopped: " in text, text
        assert truth.board("R")["now_s"] >= 3.0 or "restarted" not in text


async def test_a_step_whose_board_restarts_gives_no_figures() -> None:
    async with serve("--pty", "--fault", "restart=1.5") as server:
        proc = await _run_cli(_cli(f"--port={server.url}", "step", "--channel", "A",
                                   "--to", "45", "--hold", "30"))
        try:
            out, err = await asyncio.wait_for(proc.communicate(), 3 * PATIENCE)
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
        assert proc.returncode == 7, err.decode()
        assert "the step was stopped: board" in err.decode()
        assert "rise time" not in out.decode()
