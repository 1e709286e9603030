"""Link behaviour against a scripted fake board over real TCP on loopback."""

from __future__ import annotations

import asyncio

import pytest

from fakeboard import FakeBoard
from fpgalink import (
    BoardLost,
    Enable,
    LinkClosed,
    LinkEventKind,
    LinkState,
    ParameterError,
    ParameterRefused,
    PortError,
    RequestTimeout,
    open_link,
)

pytestmark = pytest.mark.timeout(30)


async def wait_for(predicate, timeout: float = 3.0) -> None:  # type: ignore[no-untyped-def]
    async def poll() -> None:
        while not predicate():
            await asyncio.sleep(0.005)

    await asyncio.wait_for(poll(), timeout)


async def test_set_and_get_param_confirmed() -> None:
    board = FakeBoard()
    url = await board.start()
    async with open_link(url) as link:
        assert await link.set_param("Kp_Wheel_Pid", 7.11, channel="A") == pytest.approx(7.11)
        assert await link.set_param("TsTimerPeriod", 5) == 5
        assert await link.get_param("TsTimerPeriod") == 5
        assert link.stats.retries == 0
    await board.stop()


async def test_dropped_ps_is_retried_once() -> None:
    board = FakeBoard(drop_first_ps=1)
    url = await board.start()
    async with open_link(url, request_timeout=0.05) as link:
        assert await link.set_param("MaxControlSignalB", 1000) == 1000
        assert link.stats.retries == 1
    await board.stop()


async def test_nack_names_the_reason_and_timeout_counts_tries() -> None:
    board = FakeBoard(nack=3)
    url = await board.start()
    async with open_link(url, request_timeout=0.03, request_tries=3) as link:
        with pytest.raises(ParameterRefused, match="TsTimerPeriod: value out of range"):
            await link.set_param("TsTimerPeriod", 5)
        board.nack = None
        board.drop_first_ps = 10
        with pytest.raises(RequestTimeout, match="3 tries"):
            await link.set_param("TsTimerPeriod", 5)
        # Host-side validation: nothing sent.
        before = link.stats.frames_sent
        with pytest.raises(ParameterError, match=r"1\.\.1000"):
            await link.set_param("TsTimerPeriod", 0)
        assert link.stats.frames_sent == before
    await board.stop()


async def test_sync_params_reports_each() -> None:
    board = FakeBoard()
    url = await board.start()
    async with open_link(url) as link:
        results = await link.sync_params({"TsTimerPeriod": 2, "Kp_Wheel_PidA": 1.5,
                                          "Kp_Wheel_PidB": 2.5})
        assert [r.ok for r in results] == [True, True, True]
        assert [r.confirmed for r in results] == [2, 1.5, 2.5]
    await board.stop()


async def test_heartbeat_and_disable() -> None:
    board = FakeBoard()
    url = await board.start()
    async with open_link(url, heartbeat_interval=0.02) as link:
        await link.enable()
        await wait_for(lambda: sum(isinstance(e, Enable) for e in board.received) >= 4)
        await link.disable()
        await wait_for(lambda: type(board.received[-1]).__name__ == "Disable")
        count = sum(isinstance(e, Enable) for e in board.received)
        await asyncio.sleep(0.1)
        assert sum(isinstance(e, Enable) for e in board.received) == count
    await board.stop()


async def test_telemetry_subscribers_latest_and_slow_drop() -> None:
    board = FakeBoard()
    url = await board.start()
    async with open_link(url) as link:
        fast = link.telemetry()
        slow = link.telemetry(maxsize=3)
        await wait_for(lambda: link.board_alive)
        for t in range(10):
            board.send_tm(t)
        got = [ (await fast.__anext__()).t_us for _ in range(10)]
        assert got == list(range(10))
        assert [(await slow.__anext__()).t_us for _ in range(3)] == [7, 8, 9]
        assert slow.dropped == 7 and link.stats.subscriber_drops == 7
        assert link.latest is not None and link.latest.t_us == 9
    # Closing ends iteration.
    with pytest.raises(StopAsyncIteration):
        await fast.__anext__()
    await board.stop()


async def test_board_lost_and_found() -> None:
    board = FakeBoard(alive_period=0.02)
    url = await board.start()
    async with open_link(url, liveness_timeout=0.15) as link:
        events = link.watch()
        assert (await asyncio.wait_for(events.__anext__(), 2)).kind is LinkEventKind.BOARD_FOUND
        board.silent = True
        lost = await asyncio.wait_for(events.__anext__(), 2)
        assert lost.kind is LinkEventKind.BOARD_LOST
        assert not link.board_alive and link.stats.heartbeat_misses == 1
        board.silent = False
        found = await asyncio.wait_for(events.__anext__(), 2)
        assert found.kind is LinkEventKind.BOARD_FOUND
    await board.stop()


async def test_port_lost_fails_pending_then_reconnects() -> None:
    board = FakeBoard(drop_first_ps=1000)
    url = await board.start()
    async with open_link(url, request_timeout=1.0, reconnect_backoff=(0.02, 0.1)) as link:
        await link.enable()
        events = link.watch()
        pending = asyncio.ensure_future(link.set_param("TsTimerPeriod", 3))
        await asyncio.sleep(0.05)
        await board.stop()
        with pytest.raises(BoardLost, match="port lost"):
            await asyncio.wait_for(pending, 1.0)
        assert link.state is LinkState.RECONNECTING
        with pytest.raises(BoardLost, match="disconnected"):
            await link.set_param("TsTimerPeriod", 3)
        board.drop_first_ps = 0
        await board.start(port=board.port)
        await wait_for(lambda: link.state is LinkState.CONNECTED)
        kinds = []
        while LinkEventKind.PORT_RESTORED not in kinds:
            kinds.append((await asyncio.wait_for(events.__anext__(), 2)).kind)
        assert kinds.index(LinkEventKind.PORT_LOST) < kinds.index(LinkEventKind.PORT_RESTORED)
        assert await link.set_param("TsTimerPeriod", 3) == 3
        # The heartbeat resumed on the new connection.
        await wait_for(lambda: any(isinstance(e, Enable) for e in board.received))
        assert link.stats.reconnects == 1
    await board.stop()


async def test_close_fails_pending_requests() -> None:
    board = FakeBoard(drop_first_ps=1000)
    url = await board.start()
    link = await open_link(url, request_timeout=5.0).open()
    pending = asyncio.ensure_future(link.set_param("TsTimerPeriod", 3))
    await asyncio.sleep(0.02)
    await link.close()
    with pytest.raises(LinkClosed):
        await pending
    await link.close()  # twice is fine
    with pytest.raises(LinkClosed):
        await link.enable()
    await board.stop()


async def test_missing_ports_are_port_errors() -> None:
    with pytest.raises(PortError, match=r"/dev/does-not-exist"):
        await open_link("/dev/does-not-exist").open()
    with pytest.raises(PortError, match=r"127\.0\.0\.1:1"):
        await open_link("socket://127.0.0.1:1").open()
