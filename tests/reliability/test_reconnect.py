"""20 unplug/replug cycles of a TCP-served emulated board during streaming: the Link comes
back each time with telemetry flowing, and leaks no task, file descriptor or memory."""

from __future__ import annotations

import asyncio
import os
import tracemalloc

import pytest

from fpgaemu.build import build_board
from fpgaemu.serve import PacedBoard, TcpEndpoint
from fpgalink import open_link
from fpgalink.events import PortLost, PortRestored, StatusEvent
from tests.support.emulated import scale

pytestmark = pytest.mark.timeout(60)


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


async def until(predicate, timeout: float = 5.0) -> None:  # type: ignore[no-untyped-def]
    """Wait for a condition the loop will make true; fail loudly if it does not."""
    async def poll() -> None:
        while not predicate():
            await asyncio.sleep(0.002)

    await asyncio.wait_for(poll(), timeout)


async def test_unplug_replug_cycles_leak_nothing() -> None:
    cycles = scale(20, 20)
    board = build_board(settings={"TsTimerPeriod": 10, "GetDataPeriodical": 1})
    endpoint = TcpEndpoint(PacedBoard(board), "127.0.0.1", 0)
    await endpoint.start()
    link = open_link(endpoint.url, reconnect_backoff=(0.005, 0.02))
    await link.open()
    events = link.watch()
    samples = link.telemetry(maxsize=64)
    link.enable()
    await asyncio.wait_for(samples.__anext__(), 2.0)

    async def next_port_event(kind: type[StatusEvent]) -> None:
        # Board found/lost events interleave; the port events must come in order.
        while True:
            event = await asyncio.wait_for(events.__anext__(), 2.0)
            if type(event) in (PortLost, PortRestored):
                assert type(event) is kind
                return

    async def unplug_and_back() -> float:
        loop = asyncio.get_running_loop()
        assert endpoint.host_connected
        started = loop.time()
        endpoint.unplug()  # the device side goes away, as a pulled cable does
        await next_port_event(PortLost)
        await next_port_event(PortRestored)
        while len(samples):  # samples from before the unplug
            await samples.__anext__()
        await asyncio.wait_for(samples.__anext__(), 2.0)  # streaming resumed
        return loop.time() - started

    await unplug_and_back()  # warm-up: first reconnect allocates its caches
    await until(lambda: endpoint.host_connected)
    before = asyncio.all_tasks()
    tasks0, fds0 = len(before), open_fds()
    tracemalloc.start()
    mem0 = tracemalloc.get_traced_memory()[0]
    recoveries = []
    for _ in range(cycles):
        recoveries.append(await unplug_and_back())
    # The old server-side handler finishes on its own after the new one starts.
    try:
        # + 1: the polling task of ``until`` itself.
        await until(lambda: len(asyncio.all_tasks()) <= tasks0 + 1, 2.0)
    except TimeoutError:
        extra = [t.get_coro() for t in asyncio.all_tasks() - before]
        raise AssertionError(f"tasks left over: {extra}") from None
    mem1 = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    fds1, tasks1 = open_fds(), len(asyncio.all_tasks())
    fastest, slowest = min(recoveries) * 1e3, max(recoveries) * 1e3
    print(f"\nreconnect x{cycles}: recovery {fastest:.0f}..{slowest:.0f} ms (unplug → sample), "
          f"tasks {tasks0} → {tasks1}, fds {fds0} → {fds1}, "
          f"traced memory {mem0 / 1e3:.0f} kB → {mem1 / 1e3:.0f} kB")
    assert link.stats.reconnects == cycles + 1
    assert tasks1 <= tasks0 and fds1 <= fds0
    assert mem1 - mem0 < 256_000
    await link.close()
    await endpoint.close()
