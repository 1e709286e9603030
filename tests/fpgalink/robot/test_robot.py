"""The asyncio Robot against the in-process emulated robot (``emu://robot/L``, ``…/R``):
start-up reads the boards, driving needs the deadman, a lapse or a silent board stops every
board and says why, recovery does not re-enable, go_to ends in arrival, a timeout or the
supervision event. Facts about the boards are read from the emulated boards themselves,
cycle-exact, so the checks hold however slow the machine is."""

from __future__ import annotations

import asyncio
import itertools
import math
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from typing import Any

import pytest

import fpgaemu.firmware
from fpgaemu.board import Board
from fpgaemu.firmware import Firmware
from fpgaemu.robot import EmulatedRobot
from fpgaemu.serve import FAR_END_LAG_EXTRA
from fpgaemu.timeline import CLOCK_HZ
from fpgaemu.uartcommand import EnableCause, EnableChange
from fpgalink.aio.link import Link
from fpgalink.errors import BoardLost
from fpgalink.events import (
    BoardBack,
    BoardRestarted,
    BoardResynced,
    BoardSilent,
    RestartEvidence,
    StatusEvent,
)
from fpgalink.protocol import (
    IdentityMismatch,
    LocalProtocolError,
    declarations_digest,
    declarations_hash,
    float32,
)
from fpgalink.protocol.robot import SEED_ROBOT_TOML, RobotDescription, parse_robot, seed_robot
from fpgalink.robot import GoalTimeout, Robot, RobotClosed, RobotError, RobotStopped, setup
from fpgalink.robot.arbiter import CommandNotice, Taken
from fpgalink.robot.recovery import BoardNotice
from fpgalink.robot.supervision import State, StopReason, SupervisionEvent
from tests.support.driving import drive_until
from tests.support.interpose import HeldReads, LateReads, SlowReader, interpose
from tests.support.served import PATIENCE
from tests.support.waiting import wait_until

pytestmark = pytest.mark.timeout(60)


def _ports(description: RobotDescription, query: str) -> dict[str, str]:
    return {b: f"emu://robot/{b}?{query}" for b in description.boards}


@asynccontextmanager
async def emulated(query: str = "surface=gravel", **options: Any) -> AsyncIterator[Robot]:
    description = options.pop("description", seed_robot())
    async with Robot.open(description, _ports(description, query), **options) as robot:
        yield robot


def heard_then(then: Callable[[Robot], Awaitable[None]]) -> Robot:
    """A robot (not started) on emulated boards whose start, once every board is heard,
    does ``then(robot)`` before it sets them up."""
    description = seed_robot()
    robot = Robot.open(description, _ports(description, "surface=ideal"))
    wait_for_boards = robot._wait_for_boards

    async def heard() -> None:
        await wait_for_boards()
        await then(robot)

    robot._wait_for_boards = heard  # type: ignore[method-assign]
    return robot


async def start_fails(robot: Robot, match: str) -> None:
    """The robot's start raises :class:`RobotError` matching ``match``; closed either way."""
    try:
        with pytest.raises(RobotError, match=match):
            await robot.start()
    finally:
        await robot.close()


def found_streaming(boards: tuple[str, ...], then: Callable[[Link], object],
                    until: Callable[[], bool] = lambda: True) -> Robot:
    """A robot (not started) on emulated boards whose start finds ``boards`` sending a TM
    every 1 ms (a host before left them on): once heard, they are made to stream, then
    ``then(link)`` for each, and once ``until()`` holds the robot sets them up."""

    async def streaming(robot: Robot) -> None:
        links = [robot.links[name] for name in boards]
        for link in links:
            await link.set_param("GetDataPeriodical", 1)
        await wait_until(lambda: all(link.stats.telemetry_received > 20 for link in links),
                         PATIENCE, "TM")
        for link in links:
            then(link)
        await wait_until(until, PATIENCE, "the boards found as asked")

    return heard_then(streaming)


def board(robot: Robot, name: str) -> Board:
    found = robot.links[name].get_extra_info("board")
    assert isinstance(found, Board)
    return found


def firmware(robot: Robot, name: str) -> Firmware:
    found = board(robot, name).peripherals["firmware"]
    assert isinstance(found, Firmware)
    return found


def enable_log(robot: Robot, name: str) -> list[EnableChange]:
    log: list[EnableChange] = []
    board(robot, name).uartcommand.on_enable_change(log.append)
    return log


async def test_start_loads_the_description_and_reads_the_resolution_back() -> None:
    description = parse_robot(SEED_ROBOT_TOML.replace("IncSenzRes = 500", "IncSenzRes = 400"))
    async with emulated(description=description) as robot:
        assert set(robot.resolution.values()) == {400}
        for name in ("L", "R"):
            assert firmware(robot, name).value("IncSenzRes", "A") == 400
            assert firmware(robot, name).value("GetDataPeriodical") == 1
        assert robot.state is State.DISABLED


async def test_a_confirmed_change_of_resolution_or_torque_coefficient_is_followed() -> None:
    async with emulated() as robot:
        assert robot.torque_coef[("L", 1)] == firmware(robot, "L").value("TorqueCoef", "A")
        await robot.links["L"].set_param("IncSenzRes", 250, 1)
        await robot.links["R"].set_param("TorqueCoef", 0.5, 2)
        assert robot.resolution[("L", 1)] == 250 and robot.resolution[("L", 2)] == 500
        assert robot.torque_coef[("R", 2)] == 0.5
        # Odometry and joint states read the new resolution: half the counts per turn.
        await wait_until(lambda: robot.joint_states() is not None, PATIENCE, "samples")
        sample = robot.latest["L"]
        states = robot.joint_states()
        assert states is not None
        assert states.position[0] == pytest.approx(math.tau * sample.a.position / 2500)
        assert states.position[1] == pytest.approx(math.tau * sample.b.position / 5000)


async def test_health_says_each_board_and_the_supervision_state() -> None:
    async with emulated() as robot:
        first = robot.health()
        assert [s.name for s in first] == ["board L", "board R", "supervision"]
        assert [s.level for s in first] == [0, 0, 0]
        assert dict(first[0].values)["wire use board to host"] == ""
        so_far = robot.links["L"].stats.telemetry_received
        await wait_until(lambda: robot.links["L"].stats.telemetry_received > so_far + 50,
                         PATIENCE, "telemetry")
        second = dict(robot.health()[0].values)
        assert second["wire use board to host"].endswith(" %")
        assert float(second["wire use board to host"].split()[0]) > 0


async def test_driving_needs_the_enable_and_reaches_both_boards_together() -> None:
    async with emulated() as robot:
        with pytest.raises(RobotStopped, match="not enabled"):
            robot.drive(0.1, 0.0)
        async with robot.enabled():
            command = robot.drive(0.1, math.radians(10))
            left, right = command.references["L"], command.references["R"]

            def applied() -> bool:
                return all(
                    [firmware(robot, n).channels[c].reference for c in (1, 2)]
                    == pytest.approx(list(refs), rel=1e-6)
                    for n, refs in (("L", left), ("R", right)))

            await wait_until(applied, PATIENCE, "both boards to hold the references")
            await drive_until(robot, lambda: robot.pose.x > 0.01, "the robot to move", 0.1,
                              math.radians(10))
        # Leaving the block disables: the RD reaches both boards.
        await wait_until(lambda: not board(robot, "L").global_enable
                         and not board(robot, "R").global_enable, PATIENCE, "both disabled")


async def test_a_deadman_not_renewed_disables_every_board() -> None:
    async with emulated() as robot:
        events = robot.events()
        logs = {n: enable_log(robot, n) for n in ("L", "R")}
        robot.enable()
        robot.drive(0.1, 0.0)
        stopped: list[SupervisionEvent] = []
        async for event in events:
            if event.state is State.DISABLED and not event.recovered:
                stopped.append(event)
                if event.reason is not StopReason.DEADMAN:
                    # A loaded machine's own fault came first (a stalled test process
                    # lapses the watchdog): enable again, and leave it unrenewed again.
                    await wait_until(lambda: not robot.supervisor.blocked, PATIENCE, "ready")
                    robot.enable()
                    continue
                break
        assert stopped[-1].reason is StopReason.DEADMAN
        for name in ("L", "R"):
            await wait_until(lambda n=name: logs[n] and not logs[n][-1].enabled,  # type: ignore[misc]
                             PATIENCE, f"board {name} disabled")
            assert logs[name][-1].cause is EnableCause.DISABLE  # RD, not its own watchdog
        with pytest.raises(RobotStopped, match="not enabled"):
            robot.drive(0.1, 0.0)


async def test_a_silent_board_stops_the_other_at_once_and_never_re_enables() -> None:
    # L's cable is cut from 2 s to 4 s of emulated time: L hears nothing and says nothing.
    # A loaded machine may stop the robot earlier for a reason of its own (a stalled host);
    # every fault is an event whatever the state, so the cut's are looked for among them.
    async with emulated("surface=gravel&fault=L:disconnect=2:2") as robot:
        logs = {n: enable_log(robot, n) for n in ("L", "R")}
        noticed: list[StatusEvent] = []
        robot.links["L"].on_event(lambda e: noticed.append(e)
                                  if type(e) is BoardSilent else None)
        events = robot.events()
        cut = 2 * CLOCK_HZ
        async with robot.enabled():
            robot.drive(0.05, 0.0)
            # Its telemetry stopping is the first sign (50 ms), then its silence (0.7 s).
            async for event in events:
                if event.reason is StopReason.TELEMETRY_STALE and event.board == "L" \
                        and board(robot, "L").now >= cut:
                    break
        async for event in events:
            if event.reason is StopReason.BOARD_LOST:
                break
        assert event.board == "L" and event.state is State.DISABLED
        assert noticed and event.at - noticed[0].at <= 0.05  # said in the same callback
        await wait_until(lambda: logs["R"] and not logs["R"][-1].enabled, PATIENCE,
                         "R disabled")
        assert logs["R"][-1].cause is EnableCause.DISABLE  # the robot's RD
        # L never heard an RD after the cut: its own watchdog stopped it, 300 ms after its
        # last RE (unless the robot had stopped before the cut).
        last_l = logs["L"][-1]
        assert not last_l.enabled
        assert last_l.cause is EnableCause.WATCHDOG or last_l.cycle < cut
        for name in ("L", "R"):
            for channel in board(robot, name).channels.values():
                assert channel.pwm.applied_duty == 0
        # L comes back (the cut ends at 4 s): heard after a silence, it may have restarted,
        # so it is reconfigured; the robot stays disabled until asked.
        await wait_until(lambda: robot.links["L"].board_alive, PATIENCE, "L back")
        await wait_until(lambda: not robot.supervisor.blocked, PATIENCE, "L reconfigured")
        until = board(robot, "L").now + int(0.5 * CLOCK_HZ)
        await wait_until(lambda: board(robot, "L").now > until, PATIENCE, "0.5 s more")
        assert robot.state is State.DISABLED
        assert not board(robot, "L").global_enable and not board(robot, "R").global_enable
        robot.enable()  # asked for again: now it enables
        await wait_until(lambda: board(robot, "L").global_enable
                         and board(robot, "R").global_enable, PATIENCE, "both enabled")
        robot.disable()


async def test_go_to_arrives() -> None:
    async with emulated() as robot, robot.enabled():
        for _ in range(3):
            try:
                pose = await robot.go_to(0.6, 0.3, timeout=PATIENCE * 3)
                break
            except RobotStopped as stopped:
                # A loaded machine's own fault (a stalled test process lapses the watchdog,
                # or its telemetry comes late): once ready, enable and go on from there.
                assert stopped.event is not None and stopped.event.reason in (
                    StopReason.WATCHDOG_LAPSED, StopReason.TELEMETRY_STALE)
                await wait_until(lambda: not robot.supervisor.blocked, PATIENCE, "ready")
                robot.enable()
        assert math.hypot(pose.x - 0.6, pose.y - 0.3) < robot.goto_settings.position_tolerance


async def test_go_to_times_out_cleanly_with_a_wheel_held_at_zero() -> None:
    async with emulated("surface=gravel&fault=L:wheel-stuck=A&fault=L:wheel-stuck=B"
                        ) as robot, robot.enabled():
        with pytest.raises(GoalTimeout, match=r"not at \(1, 0\) after 3 s"):
            await robot.go_to(1.0, 0.0, timeout=3.0)
        assert robot.command is None  # stopped: zero references, on their way
        await wait_until(lambda: all(c.reference == 0.0 for n in ("L", "R")
                                     for c in firmware(robot, n).channels.values()),
                         PATIENCE, "zero references on both boards")


async def test_go_to_ends_with_the_supervision_event_that_stopped_it() -> None:
    async with emulated() as robot:
        robot.enable()  # and never renewed: the deadman lapses mid-way
        with pytest.raises(RobotStopped, match="not renewed") as caught:
            await robot.go_to(5.0, 0.0, timeout=PATIENCE * 3)
        assert caught.value.event is not None
        assert caught.value.event.reason is StopReason.DEADMAN


async def test_kinematics_set_at_run_time_drive_and_count_with_the_new_values() -> None:
    async with emulated() as robot:
        before = robot.kinematics
        async with robot.enabled():
            turn = robot.drive(0.0, 0.1).references
            model = robot.set_kinematics(chi=before.chi * 2, track=0.5, wheel_radius=0.1)
            assert (model.chi, model.track, model.wheel_radius) == (before.chi * 2, 0.5, 0.1)
            again = robot.drive(0.0, 0.1).references
        # A turn in place: wheel speed ∝ χ·B / r, so 2 × (0.5 / B) × (r / 0.1) of before.
        ratio = 2 * 0.5 / before.track * before.wheel_radius / 0.1
        assert again["L"][0] == pytest.approx(turn["L"][0] * ratio, rel=1e-9)
        assert abs(again["L"][0]) < robot.description.max_wheel_speed  # not limited
        # Odometry counts with them (its radius turns counts into metres, its χ·B turns).
        assert robot.odometry.kinematics is model
        assert robot.odometry.description.wheel_radius == 0.1
        for bad in ({"chi": 0.5}, {"track": 0.0}, {"wheel_radius": math.nan}):
            with pytest.raises(ValueError):
                robot.set_kinematics(**bad)
        assert robot.kinematics is model  # nothing changed


async def test_an_emulator_slower_than_real_time_is_not_taken_for_a_failing_board(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # A loaded machine: once started, the in-process robot runs at 2/3 of real time, each
    # 50 ms slice of it taking 75 ms, its telemetry arriving in bursts 75 ms apart. The host
    # lives on the boards' time (FAR_END_LAG_EXTRA): no telemetry "stopped", no watchdog
    # lapse, no stop — while L's cable, cut at 2.5 s of its time, is still noticed as its
    # telemetry stopping.
    original = EmulatedRobot.run_until
    slowed = [False]

    def slow(self: EmulatedRobot, cycle: int) -> None:
        start = self.now
        original(self, cycle)
        if slowed[0]:
            time.sleep(1.5 * (self.now - start) / CLOCK_HZ)

    monkeypatch.setattr(EmulatedRobot, "run_until", slow)
    cut = int(2.5 * CLOCK_HZ)
    async with emulated("surface=ideal&fault=L:disconnect=2.5:5") as robot:
        assert board(robot, "L").now < cut - CLOCK_HZ  # started well before the cut
        lagging = robot.links["L"].get_extra_info(FAR_END_LAG_EXTRA)
        assert callable(lagging)
        logs = {n: enable_log(robot, n) for n in ("L", "R")}
        events = robot.events()
        worst_lag = 0.0
        slowed[0] = True
        async with robot.enabled():
            robot.drive(0.05, 0.0)
            async for event in events:
                worst_lag = max(worst_lag, lagging())
                if event.state is not State.ENABLED:
                    break
        # The first stop is the cut, seen as L's telemetry stopping, after the cut.
        assert event.reason is StopReason.TELEMETRY_STALE and event.board == "L", event
        assert board(robot, "L").now >= cut
        # Before it both boards were enabled all along: no lapse of either watchdog.
        for name in ("L", "R"):
            assert [c.cause for c in logs[name] if not c.enabled
                    and c.cycle < cut] == [], logs[name]
        assert worst_lag > 0.1  # it did fall behind the wall clock



async def test_a_loop_blocked_past_the_deadman_is_not_a_caller_that_stopped_renewing(
        ) -> None:
    # Just enabled, the process blocks for 0.6 s (a slow first import, a stall; the deadman
    # is 0.5 s): when it runs again the deadman's timer is due, and so is the renewal that
    # came due long before it. The renewal has its turn first: still enabled. (The
    # in-process boards stalled with it: no lapse.)
    async with emulated("surface=ideal") as robot:
        async with robot.enabled():
            time.sleep(0.6)
            await asyncio.sleep(0.3)
            assert robot.state is State.ENABLED, robot.last_stop
        # A caller that really stops renewing is stopped by the deadman, as before.
        events = robot.events()
        robot.enable()
        async for event in events:
            if event.state is State.DISABLED:
                break
        assert event.reason is StopReason.DEADMAN, event


async def test_a_resync_reported_with_a_new_restart_behind_it_does_not_make_the_board_ready(
        ) -> None:
    # In one batch of events the link reports restart 1's resync done, then restart 2. The
    # task that reads back after restart 1's resync belongs to restart 1: it must not take
    # restart 2 for its own (whose resync has not been reported) and say the board ready.
    async with emulated("surface=ideal") as robot:
        link = robot.links["L"]
        loop = asyncio.get_running_loop()

        def restarted() -> BoardRestarted:
            return BoardRestarted(RestartEvidence.COUNTER_RESET, "synthetic", at=loop.time())

        recovery = robot.recovery
        recovery.on_link_event("L", link, restarted())
        recovery.on_link_event("L", link, BoardResynced(3, (), at=loop.time()))
        recovery.on_link_event("L", link, restarted())
        # Restart 1's read-back is answered (the board is there) and ends.
        await wait_until(lambda: recovery.reading_back == 0, PATIENCE,
                         "the read-back after restart 1's resync")
        await asyncio.sleep(0.2)
        assert recovery.reading_back == 0  # a finished read-back is not kept
        assert "L" in recovery.reconfiguring
        assert robot.supervisor.blocked.get("L", "").startswith("restarted"), \
            robot.supervisor.blocked
        with pytest.raises(RobotStopped):
            robot.enable()


async def test_boards_left_streaming_are_set_up_by_a_host_slower_than_their_stream(
        ) -> None:
    # Both boards still send a TM every 1 ms (a host before this one left them on, or was
    # killed), and this host reads 10 kB/s of their 42 kB/s, its port keeping 100 kB as
    # serve's does: an answer waits behind more than a request's patience (5 rounds of
    # 8 × 50 ms; a ROS node started on a loaded machine gave up: "get TorqueCoefB: no
    # answer after 8 tries"). The stream is quieted first (the board takes that at once;
    # its echo comes when what waits is read), the set-up is answered, the stream turned
    # on again; close leaves it on, as it was found.
    readers: list[SlowReader] = []
    # Each port holds 3 s of reading when the set-up begins: more than a request's
    # patience (5 rounds of 8 tries 50 ms apart), for every board at once.
    robot = found_streaming(("L", "R"), lambda link: readers.append(
        interpose(link, lambda port: SlowReader(port, 10_000, backlog=100_000))),
        until=lambda: all(len(reader.waiting) > 3 * 10_000 for reader in readers))
    try:
        async with robot:
            assert len(readers) == 2
            for name in ("L", "R"):
                assert firmware(robot, name).value("GetDataPeriodical") == 1
                assert firmware(robot, name).value("IncSenzRes", "A") == 500
            assert robot._streaming_before == {"L": 1, "R": 1}
            assert set(robot.torque_coef.values()) == {float32(0.2)}
            found = [firmware(robot, name) for name in ("L", "R")]
    finally:
        for reader in readers:
            reader.stop()
    # Left on, as found.
    assert [each.value("GetDataPeriodical") for each in found] == [1, 1]


async def test_a_board_found_streaming_that_then_falls_silent_fails_the_start_saying_so(
        ) -> None:
    # L streams, then nothing it sends reaches this host: its quiet is never confirmed, and
    # the start fails naming the board and the step (the CLI's exit 4), not a hang.
    def silent(link: Link) -> None:
        interpose(link, HeldReads).held = True

    await start_fails(found_streaming(("L",), silent),
                      "board L not answering: turning its telemetry off to set it up: "
                      "board silent for")


async def test_a_board_that_falls_silent_while_it_is_set_up_is_named_with_the_step() -> None:
    # Heard, not streaming, then nothing it sends reaches this host: the start fails naming
    # the board and the step, as "not answering" (exit 4 in the CLI and the node), where the
    # link's own error named neither ("board silent for 0.702 s").
    async def silent(robot: Robot) -> None:
        interpose(robot.links["L"], HeldReads).held = True

    await start_fails(heard_then(silent), "board L not answering: asking whether it streams: ")


@pytest.mark.parametrize("held_from", [BoardRestarted,
                                       BoardResynced])
async def test_a_restarted_board_heard_late_past_its_silence_is_still_reconfigured(
        held_from: type[StatusEvent]) -> None:
    # L restarts at 1.5 s; from the moment its link sets it up again (or reads it back), its
    # answers reach this host 1 s late: past the liveness timeout, so L is lost mid-way, then
    # heard going on (no second restart). What was interrupted goes on; the robot drives
    # again. (It stayed "restarted: reconfiguring" for good on a loaded machine: the late
    # answer made the board "back" and the link had dropped the rest of its resync.)
    async with emulated("surface=ideal&fault=L:restart=1.5") as robot:
        link = robot.links["L"]
        held = interpose(link, HeldReads)
        seen: list[type[StatusEvent]] = []
        loop = asyncio.get_running_loop()

        def on_event(event: StatusEvent) -> None:
            seen.append(type(event))
            if type(event) is held_from and not held.waiting and seen.count(held_from) == 1:
                held.held = True
                loop.call_later(1.0, held.release)

        link.on_event(on_event)
        await drive_until(robot, lambda: BoardBack in seen, "L lost and back")
        assert seen.count(BoardRestarted) == 1
        assert BoardSilent in seen
        x = robot.pose.x
        await drive_until(robot, lambda: not robot.supervisor.blocked and robot.pose.x > x + 0.1,
                          "driving again after L's reconfiguration")
        assert seen.count(BoardRestarted) == 1
        assert seen.count(BoardResynced) == 1  # a paused resync goes on
        statuses = {s.name: s for s in robot.health()}
        assert statuses["board L"].level.name == "OK", statuses["board L"]
        assert firmware(robot, "L").value("GetDataPeriodical") == 1
        robot.disable()


async def test_a_restarted_board_answering_later_than_a_requests_tries_is_reconfigured(
        ) -> None:
    # From L's restart on, its every answer comes 0.45 s late: after a request's 8 tries of
    # 50 ms, and nearly its liveness timeout. Nothing it was asked counts as refused: each
    # setting and each read-back is asked again until an answer confirms it (a late answer
    # confirms the request asked again). The robot drives again.
    async with emulated("surface=ideal&fault=L:restart=1.5") as robot:
        link = robot.links["L"]
        seen: list[StatusEvent] = []

        def on_event(event: StatusEvent) -> None:
            seen.append(event)
            if type(event) is BoardRestarted:
                interpose(link, lambda port: LateReads(port, 0.45))

        link.on_event(on_event)
        x = robot.pose.x
        await drive_until(robot, lambda: any(type(e) is BoardResynced
                                             for e in seen)
                          and not robot.supervisor.blocked and robot.pose.x > x + 0.1,
                          "driving again after L's reconfiguration")
        assert [type(e) for e in seen].count(BoardRestarted) == 1
        (resynced,) = [e for e in seen if type(e) is BoardResynced]
        assert "confirmed" in resynced.describe(), resynced
        assert link.stats.retries > 8  # answers did come too late for a request's tries
        statuses = {s.name: s for s in robot.health()}
        assert statuses["board L"].level.name == "OK", statuses["board L"]
        robot.disable()


async def _at_rest(robot: Robot) -> tuple[float, float, float, float]:
    """Wheels to rest, the enable held, until the body and odometry are still: the
    odometry's (x, y) and the truth's, where neither is moving (so no timing between them
    counts)."""
    loop = asyncio.get_running_loop()
    give_up = loop.time() + 3 * PATIENCE

    def still() -> bool:
        truth = robot.truth()
        assert truth is not None
        return (abs(truth["v"]) < 1e-3 and abs(truth["omega"]) < 1e-3
                and abs(robot.odometry_state.v) < 1e-3)

    while not still():
        if loop.time() > give_up:
            raise TimeoutError("the robot never came to rest")
        robot.stop()
        robot.enable()
        await asyncio.sleep(0.02)
    truth = robot.truth()
    assert truth is not None
    return robot.pose.x, robot.pose.y, float(truth["x"]), float(truth["y"])


async def test_odometry_after_a_board_restart_follows_every_boards_wheels() -> None:
    # Issue 37.13, through the robot on the physics body: L restarts mid-drive; once the
    # robot drives again, odometry must count both sides' wheels as before, within the 2 %
    # docs/robot.md promises on a straight line. (It counted L's new counters, which the
    # emulator no longer turned: 0.205 m against the body's 0.427 m, and a turn.)
    async with emulated("body=mujoco&surface=gravel&fault=L:restart=1.5") as robot:
        link = robot.links["L"]
        await drive_until(robot, lambda: link.stats.restarts > 0
                          and not robot.supervisor.blocked and robot.state is State.ENABLED,
                          "L restarted and the robot enabled again", v=0.2)
        odom_x, odom_y, true_x, true_y = await _at_rest(robot)
        x0 = robot.pose.x
        await drive_until(robot, lambda: robot.pose.x > x0 + 0.4, "0.4 m after the restart",
                          v=0.2)
        odom_x1, odom_y1, true_x1, true_y1 = await _at_rest(robot)
        assert link.stats.restarts == 1
        odometry = math.hypot(odom_x1 - odom_x, odom_y1 - odom_y)
        truth = math.hypot(true_x1 - true_x, true_y1 - true_y)
        assert truth > 0.4
        assert odometry == pytest.approx(truth, rel=0.02), (odometry, truth)
        assert abs(robot.pose.theta) < math.radians(3)
        robot.disable()


async def test_a_closed_robot_refuses_every_command() -> None:
    # Issue 37.9: after close, enable() returned without error and the state read ENABLED
    # until the deadman fired, every board's link closed. Every command now raises, as a
    # closed Link's do; the state stays what close left (disabled); close again is quiet.
    description = seed_robot()
    robot = Robot.open(description, _ports(description, "surface=ideal"))
    await robot.start()
    robot.enable()
    await robot.close()
    assert robot.state is State.DISABLED
    for call in (robot.enable, robot.disable, robot.stop, lambda: robot.drive(0.1, 0.0)):
        with pytest.raises(RobotClosed):
            call()
    with pytest.raises(RobotClosed):
        await robot.go_to(1.0, 0.0)
    with pytest.raises(RobotClosed):
        async with robot.enabled():
            pass
    assert robot.state is State.DISABLED
    await robot.close()


async def test_an_enable_a_board_refused_is_a_failed_enable_said_and_stopped(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # Issue 37.9: the robot suppressed a link's refusal to enable (its port gone a moment
    # before its link said so, say) and reported ENABLED with that board never enabled.
    async with emulated("surface=ideal") as robot:
        logs = {n: enable_log(robot, n) for n in ("L", "R")}

        def refuse() -> None:
            raise BoardLost("R: port is disconnected (reconnecting)")

        monkeypatch.setattr(robot.links["R"], "enable", refuse)
        events = robot.events()
        with pytest.raises(RobotStopped, match="board R") as raised:
            robot.enable()
        assert robot.state is State.DISABLED
        assert raised.value.event is not None
        assert raised.value.event.reason is StopReason.ENABLE_FAILED
        event = await asyncio.wait_for(events.__anext__(), PATIENCE)
        if event.reason is None:  # enabled, L's RE sent, before R refused
            event = await asyncio.wait_for(events.__anext__(), PATIENCE)
        assert event.reason is StopReason.ENABLE_FAILED and event.board == "R", event
        assert "port is disconnected" in event.detail
        # L, enabled before R refused, got its RD.
        await wait_until(lambda: logs["L"] and not logs["L"][-1].enabled, PATIENCE,
                         "L disabled")
        assert logs["L"][-1].cause is EnableCause.DISABLE
        assert not logs["R"] or not logs["R"][-1].enabled
        with pytest.raises(RobotStopped, match="not enabled"):
            robot.drive(0.1, 0.0)


async def test_a_flood_of_commands_does_not_starve_the_enables_renewal() -> None:
    # A teleop without the deadman (the node's require_enable false): the robot renews
    # its enable itself while a command comes on every turn of the loop for 2 s. (Each
    # command re-armed the renewal's timer, cancelling it from the ready queue before it
    # could run: the deadman lapsed, again and again, under a cmd_vel flood.)
    async with emulated("surface=ideal&body=kinematic") as robot:
        robot.keep_enabled(0.125)
        robot.arbiter.auto_enable = True
        events = robot.events()
        loop = asyncio.get_running_loop()
        end = loop.time() + 2.0
        sent = 0

        def flood() -> None:
            nonlocal sent
            robot.teleop.velocity(0.05, 0.0)
            sent += 1
            if loop.time() < end:
                loop.call_soon(flood)

        loop.call_soon(flood)
        while loop.time() < end + 0.2:
            await asyncio.sleep(0.05)
        stops = []
        while len(events):
            event = await events.__anext__()
            if event.state is State.DISABLED and not event.recovered:
                stops.append(event)
        assert sent > 10  # a command on every turn of the loop, however slow the machine
        assert not [e for e in stops if e.reason is StopReason.DEADMAN], stops
        assert robot.state is State.ENABLED
        robot.disable()


async def test_a_teleop_command_before_the_enable_is_held_and_driven_when_it_comes() -> None:
    # cmd_vel's first message often overtakes enable's: held, then driven by the enable
    # within the command timeout (said as a notice with what it drove); a stale one never.
    async with emulated("surface=ideal&body=kinematic") as robot:
        robot.arbiter.command_timeout = 0.5
        notices: list[Any] = []
        robot.on_notice(notices.append)
        held = robot.teleop.velocity(0.1, 0.0)
        assert held.taken is Taken.HELD and "not enabled" in held.reason
        robot.enable()
        sent = [n for n in notices if isinstance(n, CommandNotice)]
        assert sent and sent[-1].command is not None and sent[-1].command.v == 0.1
        await wait_until(lambda: firmware(robot, "L").channels[1].reference != 0.0,
                         PATIENCE, "L driven by the held command")
        robot.disable()
        robot.teleop.velocity(0.1, 0.0)
        await asyncio.sleep(0.6)  # older than the command timeout when the enable comes
        robot.enable()
        assert robot.command is None
        robot.disable()


async def test_a_timed_command_that_runs_out_brings_the_wheels_to_rest_and_is_said(
        ) -> None:
    async with emulated("surface=ideal&body=kinematic") as robot:
        robot.arbiter.command_timeout = 0.2
        notices: list[Any] = []
        robot.on_notice(notices.append)
        async with robot.enabled():
            driven = robot.teleop.velocity(0.1, 0.0)
            assert driven.taken is Taken.DRIVEN
            await wait_until(lambda: any(isinstance(n, CommandNotice) for n in notices),
                             PATIENCE, "the command's timeout")
            (notice,) = [n for n in notices if isinstance(n, CommandNotice)]
            assert "no command for 0.2 s: wheels to rest" in notice.text
            await wait_until(lambda: all(firmware(robot, b).channels[c].reference == 0.0
                                         for b in ("L", "R") for c in (1, 2)),
                             PATIENCE, "every reference 0")
            assert robot.state is State.ENABLED  # to rest, still enabled


async def test_wheel_references_reach_each_wheel_with_its_boards_sign() -> None:
    # BR mounted the other way round (forward -1): a forward-positive reference is sent
    # to it negated; wheels not named get 0; unknown wheels are refused, nothing sent.
    br_block = 'board = "R"\nchannel = "B"\nx = -0.29\ny = -0.33\nforward = 1'
    assert br_block in SEED_ROBOT_TOML
    description = parse_robot(SEED_ROBOT_TOML.replace(br_block, br_block[:-1] + "-1"))
    assert description.wheel("BR").forward == -1
    async with emulated("surface=ideal&body=kinematic", description=description) as robot:
        with pytest.raises(RobotStopped, match="not enabled"):
            robot.set_wheel_references({"FL": 10.0})
        async with robot.enabled():
            robot.set_wheel_references({"FL": 12.0, "BR": -7.0})
            br = robot.description.wheel("BR")
            await wait_until(lambda: firmware(robot, "L").channels[1].reference == 12.0
                             and firmware(robot, "R").channels[br.channel].reference
                             == -7.0 * br.forward, PATIENCE, "the references on the boards")
            assert firmware(robot, "L").channels[2].reference == 0.0
            with pytest.raises(LocalProtocolError, match="no wheel"):
                robot.set_wheel_references({"XX": 1.0})


def test_sample_sets_are_stamped_by_each_boards_own_time() -> None:
    """On emulated time: the stamps are a function of the boards' clocks and the arrivals,
    not of how this machine scheduled the test (on the wall clock a loaded machine's late
    arrivals settled the boards' mappings apart by 6 ms)."""
    from fpgalink.aio.virtualtime import run_virtual

    async def main() -> list[Any]:
        async with emulated("surface=ideal&body=kinematic") as robot:
            sets = robot.sample_sets(min_period=0.01)
            got = []
            async for stamped in sets:
                got.append(stamped)
                if len(got) == 60:
                    break
            sets.close()
            return got

    got = run_virtual(main())
    assert all(s.clocked for s in got)
    for stamped in got[-10:]:
        # Each sample on the host's clock by its board's own time: the boards' stamps
        # are as far apart as their t_us (their mapping settled within a few ms).
        apart_us = stamped.samples["R"].t_us - stamped.samples["L"].t_us
        assert abs((stamped.stamps["R"] - stamped.stamps["L"]) / 1000 - apart_us) < 5000
        assert stamped.stamp == stamped.stamps["L"]
    spacing = [b.stamp - a.stamp for a, b in itertools.pairwise(got)]
    assert min(spacing) > 0  # in order, at most one set per 10 ms of arrival
    assert [s.odometry_stamp for s in got] == sorted(s.odometry_stamp for s in got)


async def test_a_stale_telemetry_limit_set_on_the_boards_is_their_connections_own() -> None:
    # The ROS node's telemetry_timeout_periods reaches each board's connection through
    # Boards.set_stale_periods: its settings, checked as every new value is (after the
    # connection split the old attribute was one nothing read: the limit stayed 50).
    async with emulated("surface=ideal") as robot:
        robot.boards.set_stale_periods(1000)
        assert {link.connection.settings.stale_periods
                for link in robot.links.values()} == {1000}
        with pytest.raises(ValueError, match="stale_periods"):
            robot.boards.set_stale_periods(1)
        assert {link.connection.settings.stale_periods
                for link in robot.links.values()} == {1000}


def test_a_robot_reading_in_batches_is_brought_to_the_present_by_read_now() -> None:
    """``Robot.open(read_latency=…)``: the links read in batches (the robot hears its
    boards up to a batch late); ``read_now()`` takes what waits, and the robot's latest
    samples (what its odometry was fed) are then the boards' present's — here, in process,
    up to one catch-up slice behind (the idle robot is run again from where it was left)."""
    from fpgalink.aio.virtualtime import run_virtual

    async def main() -> tuple[list[float], list[float]]:
        description = seed_robot()
        async with Robot.open(description, _ports(description, "surface=ideal&run=batched"),
                              read_latency=0.01) as robot:
            loop = asyncio.get_running_loop()
            assert all(link.read_latency == 0.01 for link in robot.links.values())
            behind, caught_up = [], []
            for _ in range(40):
                await asyncio.sleep(0.00731)  # anywhere within a batch
                now_us = loop.time() * 1e6
                behind.append(max(now_us - robot.latest[b].t_us for b in robot.latest))
                await robot.read_now()
                caught_up.append(max(now_us - robot.latest[b].t_us
                                     for b in robot.latest))
            return behind, caught_up

    behind, caught_up = run_virtual(main())
    assert max(behind) > 3_000  # the batches were there: up to 10 ms late
    # After read_now: within a catch-up slice (10 ms) of the present, and never further
    # behind than before it (each read_now reads everything the far end has sent).
    assert max(caught_up) < 10_000 + 1_000
    assert all(c <= b for b, c in zip(behind, caught_up, strict=True))


# --- who the boards are (docs/protocol.md §8) ---------------------------------------------

OTHER_DECLARATION = declarations_hash() ^ 0x00FF_00FF_00FF_00FF


async def test_start_refuses_boards_built_from_another_declaration(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # The emulated firmware answers IQ with the hash its code was built from: here another
    # declaration's. Start refuses, naming the board and both hashes, before it sets any
    # parameter of the description on it.
    monkeypatch.setattr(fpgaemu.firmware, "declarations_hash", lambda: OTHER_DECLARATION)
    configured: list[str] = []
    configure = setup.configure

    async def recorded(name: str, *args: Any) -> Any:
        configured.append(name)
        return await configure(name, *args)

    monkeypatch.setattr(setup, "configure", recorded)
    description = seed_robot()
    robot = Robot.open(description, _ports(description, "surface=ideal"))
    with pytest.raises(IdentityMismatch) as caught:
        await robot.start()
    assert str(caught.value).startswith("board L (emu://robot/L")
    assert f"{OTHER_DECLARATION:016x}" in str(caught.value)
    assert declarations_digest() in str(caught.value)
    assert configured == []  # no board was set up
    async with emulated("surface=ideal", allow_mismatch=True) as allowed:
        statuses = {s.name: s for s in allowed.health()}
        level, values = statuses["board L"].level, dict(statuses["board L"].values)
        assert level.name == "WARN" and "another protocol" in statuses["board L"].message
        assert values["protocol"] == f"{OTHER_DECLARATION:016x}"
        assert values["host protocol"] == declarations_digest()
        assert "NOT this host's protocol" in values["identity"]


async def test_health_says_who_each_board_is() -> None:
    async with emulated("surface=ideal") as robot:
        values = {s.name: dict(s.values) for s in robot.health()}
        assert values["board L"]["identity"] == robot.boards.identity("L")[0].describe()  # type: ignore[union-attr]
        assert values["board L"]["protocol"] == values["board L"]["host protocol"] == \
            declarations_digest()


@pytest.mark.parametrize("allow", [False, True])
async def test_a_board_restarted_into_another_declaration_is_not_ready_again(
        monkeypatch: pytest.MonkeyPatch, allow: bool) -> None:
    # A re-flash changes who the board is: after L's restart its link asks again, and L
    # answers another declaration's hash. It stays not ready (the robot stopped at the
    # restart) and says why; unless the robot allows it, then it is ready once set up.
    notices: list[BoardNotice] = []
    async with emulated("surface=ideal&fault=L:restart=1.5", allow_mismatch=allow) as robot:
        robot.on_notice(lambda n: notices.append(n) if isinstance(n, BoardNotice) else None)
        monkeypatch.setattr(fpgaemu.firmware, "declarations_hash", lambda: OTHER_DECLARATION)
        await wait_until(lambda: any(n.kind == "board_identified" for n in notices),
                         PATIENCE, "L asked who it is after its restart")
        (said,) = [n for n in notices if n.kind == "board_identified"]
        assert f"{OTHER_DECLARATION:016x}" in said.detail and said.fault is not allow
        if not allow:
            await wait_until(lambda: "another protocol" in robot.supervisor.blocked.get("L", ""),
                             PATIENCE, "L kept not ready")
            with pytest.raises(RobotStopped, match="another protocol"):
                robot.enable()
            statuses = {s.name: s for s in robot.health()}
            assert statuses["board L"].level.name == "ERROR"
        else:
            await wait_until(lambda: not robot.supervisor.blocked, PATIENCE, "L ready again")
            robot.enable()
            robot.disable()
        assert robot.boards.identity("L")[0] is not None
        assert robot.boards.identity("L")[0].declarations == OTHER_DECLARATION  # type: ignore[union-attr]
