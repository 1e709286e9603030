"""``fpgaemu serve`` as a process: it starts, is reachable, and shuts down cleanly."""

from __future__ import annotations

import asyncio
import os
import signal
import time

import pytest
import serial

from fpgalink.aio import open_link
from tests.support.served import PATIENCE, serve, wait_until

pytestmark = pytest.mark.timeout(20)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
async def test_pty_serve_exits_0_on_signal_and_removes_the_device(sig: int) -> None:
    async with serve("--pty", boards=2) as server:
        paths = list(server.ready.values())
        assert all(os.path.exists(p) for p in paths)
        # Reachable: a link hears the board's alive frames.
        async with open_link(paths[0]) as link:
            await wait_until(lambda: link.stats.alive_received >= 1, PATIENCE, "an E frame")
        await server.send_signal(sig)
        assert await server.wait(5.0) == 0
        stderr = await server.stderr_text()
        assert "Traceback" not in stderr, stderr
        for path in paths:
            await wait_until(lambda p=path: not os.path.exists(p), 1.0,  # type: ignore[misc]
                             f"{path} to disappear")


def _raw_read_alive(url: str, window: float) -> tuple[bytes, float]:
    """Open ``url`` with pyserial's own ``socket://`` backend, read raw bytes until an
    ``SEP`` frame shows up or ``window`` seconds from connecting pass; returns what was read
    and how long it took. (pyserial's socket ``close()`` itself sleeps 0.3 s.)"""
    start = time.monotonic()
    port = serial.serial_for_url(url, timeout=0.02)
    try:
        data = b""
        while b"SEP" not in data and time.monotonic() - start < window:
            data += port.read(4096)
        return data, time.monotonic() - start
    finally:
        port.close()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
async def test_tcp_serve_raw_alive_frames_and_clean_exit(sig: int) -> None:
    async with serve("--tcp", "127.0.0.1:0") as server:
        url = server.url
        host, port = url.removeprefix("socket://").split(":")
        data, took = await asyncio.to_thread(_raw_read_alive, url, PATIENCE)
        assert b"SEP" in data, f"no alive frame in {took:.3f} s: {data!r}"
        # The board sends E every 300 ms, so a second one follows the first.
        data, took = await asyncio.to_thread(_raw_read_alive, url, PATIENCE)
        assert b"SEP" in data, f"no alive frame in {took:.3f} s on reconnect: {data!r}"
        await server.send_signal(sig)
        assert await server.wait(5.0) == 0
        assert "Traceback" not in await server.stderr_text()
        with pytest.raises(OSError):
            _, writer = await asyncio.open_connection(host, int(port))
            writer.close()



async def test_closing_a_link_releases_the_serial_port_at_once() -> None:
    """Close right after an RD was queued: the port must be free for the next open (the
    transport flushes first; close waits for it). Reopening used to fail with "could not
    exclusively lock port"."""
    async with serve("--pty") as srv:
        for _ in range(3):
            async with open_link(srv.url) as link:
                link.enable()
                assert await link.get_param("TsTimerPeriod") == 1
