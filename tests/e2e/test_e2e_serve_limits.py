"""``fpgaemu serve`` at its limits (issue 24, items 1, 2 and 9): descriptors above
``select()``'s 1024, a cap on truth readers, running out of descriptors, readers that stop
reading, many readers at once, and the addresses it prints for a wildcard listener. Through
a real ``fpgaemu serve`` process, except where the test counts work inside it."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import resource
import signal
import socket
import sys
from collections.abc import AsyncIterator
from typing import Any

import pytest

from fpgaemu.robot import EmulatedRobot
from fpgaemu.serve import MAX_TRUTH_READERS, PacedRobot, TruthEndpoint
from fpgalink.aio import open_link
from tests.support.cli import run_cli
from tests.support.served import PATIENCE, wait_until
from tests.support.serving import Served, serve, served, start_serve

pytestmark = pytest.mark.timeout(90)


def open_fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def truth_address(server: Served) -> tuple[str, int]:
    url = server.truth
    assert url is not None
    host, port = url.removeprefix("socket://").rsplit(":", 1)
    return host.strip("[]"), int(port)


@contextlib.asynccontextmanager
async def robot_served(*args: str, **popen: Any) -> AsyncIterator[Served]:
    """``fpgaemu serve --robot --pty``: boards L and R, and the truth."""
    async with serve("--robot", "--pty", *args, **popen) as server:
        yield server


async def first_line(host: str, port: int) -> bytes:
    reader, writer = await asyncio.open_connection(host, port)
    try:
        return await asyncio.wait_for(reader.readline(), PATIENCE)
    finally:
        writer.close()


async def stop(server: Served) -> str:
    assert await server.stopped(signal.SIGTERM) == 0
    stderr = server.log_text()
    assert "Traceback" not in stderr, stderr
    return stderr


# --- 1. select() and descriptors ----------------------------------------------------------------

#: Descriptors the serve process starts with, all below 1100: every one it opens itself is
#: then above select()'s limit of 1024.
INHERITED = 1100
PRELUDE = (
    "import os, resource, sys\n"
    "soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)\n"
    "resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, 4096), hard))\n"
    f"for _ in range({INHERITED}):\n"
    "    os.set_inheritable(os.open(os.devnull, os.O_RDONLY), True)\n"
    "os.execv(sys.executable, [sys.executable, '-m', 'fpgaemu', *sys.argv[1:]])\n"
)


@pytest.mark.skipif(resource.getrlimit(resource.RLIMIT_NOFILE)[1] < 1400,
                    reason="the hard descriptor limit is below 1400")
async def test_serve_works_with_every_descriptor_above_1024() -> None:
    # The loop used select(): "filedescriptor out of range in select()" and a dead serve.
    server = await asyncio.to_thread(
        start_serve, "--robot", "--tcp", "127.0.0.1:0", "--boards", "2",
        command=(sys.executable, "-c", PRELUDE), close_fds=True)
    try:
        async with open_link(server.ready["L"]) as link:
            assert await link.get_param("TsTimerPeriod") == 1
        assert json.loads(await first_line(*truth_address(server)))["surface"]
        assert max(int(fd) for fd in os.listdir(f"/proc/{server.proc.pid}/fd")) >= INHERITED
    finally:
        await stop(server)


async def test_truth_readers_beyond_the_cap_are_told_busy_and_the_boards_go_on() -> None:
    async with robot_served() as server:
        host, port = truth_address(server)
        connections = [await asyncio.open_connection(host, port)
                       for _ in range(MAX_TRUTH_READERS + 8)]
        try:
            lines = await asyncio.gather(*(asyncio.wait_for(reader.readline(), PATIENCE)
                                           for reader, _ in connections))
            poses = [json.loads(line) for line in lines]
            refused = [p for p in poses if "error" in p]
            assert len(refused) == 8, refused
            assert all(p == {"error": f"busy: {MAX_TRUTH_READERS} truth readers are "
                                      "connected, the most serve takes"} for p in refused)
            for (reader, _), pose in zip(connections, poses, strict=True):
                if "error" in pose:  # and then closed
                    assert await asyncio.wait_for(reader.read(), PATIENCE) == b""
            async with open_link(server.ready["L"]) as link:
                assert await link.get_param("TsTimerPeriod") == 1
        finally:
            for _, writer in connections:
                writer.close()
        assert "8 reader(s) turned away" in await stop(server)


def few_descriptors() -> None:
    """In the serve child: a descriptor limit a little above what it opens to start."""
    resource.setrlimit(resource.RLIMIT_NOFILE, (24, 24))


async def test_out_of_descriptors_serve_turns_connections_away_and_says_so_once() -> None:
    # With select() gone, the next limit is the descriptors themselves: serve used to log
    # a traceback for every refused accept (10,000 lines) and serve nothing more.
    async with robot_served(preexec_fn=few_descriptors) as server:
        host, port = truth_address(server)
        connections = [await asyncio.open_connection(host, port) for _ in range(20)]
        try:
            lines = await asyncio.gather(*(asyncio.wait_for(reader.readline(), PATIENCE)
                                           for reader, _ in connections))
            said = [json.loads(line) for line in lines]
            starved = [s for s in said if s.get("error") ==
                       "busy: serve has no file descriptor left"]
            assert starved and len(starved) < len(said), said  # some served, some not
            # The boards are served all the while: the pty needs no new descriptor.
            async with open_link(server.ready["L"]) as link:
                assert await link.get_param("TsTimerPeriod") == 1
        finally:
            for _, writer in connections:
                writer.close()
        stderr = await stop(server)
    said_once = [li for li in stderr.splitlines() if "out of file descriptors" in li]
    assert len(said_once) == 1, stderr
    assert said_once[0].startswith("fpgaemu: out of file descriptors")
    assert f"truth: {len(starved)} connection(s) turned away for want of a file " \
           "descriptor" in stderr


# --- 2. truth readers that do not read, and many that do ----------------------------------------


async def test_a_truth_reader_that_stops_reading_is_aborted_not_kept() -> None:
    # After the buffer cap, serve used to wait for the buffer to drain: the descriptor and
    # over a MiB stayed as long as the reader kept the connection open.
    async with robot_served() as server:
        host, port = truth_address(server)
        baseline = open_fds(server.proc.pid)
        stalled = []
        for _ in range(3):
            sock = socket.socket()
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # fills fast
            sock.connect((host, port))
            stalled.append(sock)
        try:
            await wait_until(lambda: open_fds(server.proc.pid) == baseline + 3, PATIENCE,
                             "serve to take the three readers")
            # Never read; still connected. Serve lets them go, descriptors and buffers.
            await wait_until(lambda: open_fds(server.proc.pid) == baseline, 3 * PATIENCE,
                             "serve to let the readers that do not read go")
        finally:
            for sock in stalled:
                sock.close()
        assert "3 reader(s) let go for not reading" in await stop(server)


async def test_each_truth_line_is_built_once_however_many_read_it() -> None:
    # 800 readers took 94 % of a core and made serve lag: each built its own line.
    robot = PacedRobot(EmulatedRobot())
    built = 0
    truth_record = robot.truth_record

    def counted() -> dict[str, Any]:
        nonlocal built
        built += 1
        return truth_record()

    robot.truth_record = counted  # type: ignore[method-assign]
    endpoint = TruthEndpoint(robot, "127.0.0.1", 0)
    await endpoint.start()
    readers = [await asyncio.open_connection("127.0.0.1", endpoint.port) for _ in range(20)]
    try:
        await wait_until(lambda: endpoint.readers == 20, PATIENCE, "20 readers")
        before = built
        first_reader = readers[0][0]
        for _ in range(10):
            await asyncio.wait_for(first_reader.readline(), PATIENCE)
        for reader, _ in readers[1:]:  # the others got the same lines
            await asyncio.wait_for(reader.readline(), PATIENCE)
        # One line per period for all twenty: about ten built, not two hundred.
        assert built - before <= 12, built - before
        assert built == endpoint.publications
    finally:
        for _, writer in readers:
            writer.close()
        await endpoint.close()


# --- 9. the addresses serve prints --------------------------------------------------------------


def _has_ipv6_loopback() -> bool:
    try:
        with socket.socket(socket.AF_INET6) as probe:
            probe.bind(("::1", 0))
    except OSError:
        return False
    return True


@pytest.mark.skipif(not _has_ipv6_loopback(), reason="no IPv6 loopback here")
def test_a_wildcard_listener_prints_one_usable_address_per_socket() -> None:
    # `--tcp :0` printed socket://:PORT (which fpgalink-cli refuses), and the IPv4 and
    # IPv6 sockets had different ports with only one printed.
    with served("--robot", "--tcp", ":0", "--truth", ":0") as server:
        assert len(server.lines) == 6, server.lines
        by_name: dict[str, list[str]] = {}
        for word, name, url in server.lines:
            assert word == "ready"
            by_name.setdefault(name, []).append(url)
        assert sorted(by_name) == ["L", "R", "truth"]
        for urls in by_name.values():
            assert [u.split("://")[1].rsplit(":", 1)[0] for u in urls] == \
                ["127.0.0.1", "[::1]"], urls
            assert len({u.rsplit(":", 1)[1] for u in urls}) == 1, urls  # one port
        for url in by_name["L"]:  # each works as given
            done = run_cli("param", "get", "TsTimerPeriod", "--port", url)
            assert done.returncode == 0, (url, done.stderr)
        for url in by_name["truth"]:
            host, port = url.removeprefix("socket://").rsplit(":", 1)
            with socket.create_connection((host.strip("[]"), int(port)), timeout=PATIENCE) \
                    as sock, sock.makefile("rb") as stream:
                assert "x" in json.loads(stream.readline())
        assert server.stop() == 0
        assert "Traceback" not in server.log_text(), server.log_text()
