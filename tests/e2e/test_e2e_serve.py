"""``fpgaemu serve`` as a process: it starts, is reachable, and shuts down cleanly."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial

from fpgalink import BoardLost, LinkClosed
from fpgalink.aio import open_link
from fpgalink.protocol import ParamAck, ParamGet
from tests.support.flood import board_counts, rss_kb
from tests.support.served import (
    PATIENCE,
    connect_when_free,
    open_when_free,
    wait_until,
)
from tests.support.serving import ServeExited, serve, served
from tests.support.wire import received as wire_received
from tests.support.wire import sent as wire_sent

pytestmark = pytest.mark.timeout(20)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
async def test_pty_serve_exits_0_on_signal_and_removes_the_device(sig: int) -> None:
    async with serve("--pty", "--boards", "2") as server:
        paths = list(server.ready.values())
        assert all(os.path.exists(p) for p in paths)
        # Reachable: a link hears the board's alive frames.
        async with open_link(paths[0]) as link:
            await wait_until(lambda: link.stats.alive_received >= 1, PATIENCE, "an E frame")
        assert await server.stopped(sig) == 0
        stderr = server.log_text()
        assert "Traceback" not in stderr, stderr
        for path in paths:
            await wait_until(lambda p=path: not os.path.exists(p), 1.0,  # type: ignore[misc]
                             f"{path} to disappear")


def _raw_read_alive(url: str, window: float) -> tuple[bytes, float]:
    """Open ``url`` with pyserial's own ``socket://`` backend, read raw bytes until an
    ``SEP`` frame shows up or ``window`` seconds from connecting pass; returns what was read
    and how long it took. (pyserial's socket ``close()`` itself sleeps 0.3 s.) Serve takes
    one host at a time, so a connection right after another may be refused for a moment."""
    start = time.monotonic()
    while True:
        try:
            port = serial.serial_for_url(url, timeout=0.02)
            break
        except serial.SerialException:
            if time.monotonic() - start > window:
                raise
            time.sleep(0.02)
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
        assert await server.stopped(sig) == 0
        assert "Traceback" not in server.log_text()
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


# --- hostile and careless hosts ---------------------------------------------------------------


@pytest.mark.timeout(60)
async def test_a_client_flooding_tcp_is_held_back_loses_nothing_and_memory_stays_flat() -> None:
    # Once 4.9 GB were taken from a TCP client in 30 s; then the excess was dropped. Now the
    # client is held back to the line's rate, and every byte it wrote reaches the board.
    async with serve("--tcp", "127.0.0.1:0") as server:
        host, port = server.url.removeprefix("socket://").rsplit(":", 1)
        before = rss_kb(server.proc.pid)
        loop = asyncio.get_running_loop()
        sock = socket.socket()
        # A fixed send buffer: the kernel would grow it to megabytes (all of it then crossing
        # the line before the request below), which is allowed but makes a slow test.
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 16 * 1024)
        sock.setblocking(False)
        await loop.sock_connect(sock, (host, int(port)))
        reader, writer = await asyncio.open_connection(sock=sock)
        chunk = b"\x00" * 65536
        start = loop.time()
        sent = 0
        while loop.time() < start + 2.0:
            writer.write(chunk)
            await writer.drain()  # as fast as serve lets it
            sent += len(chunk)
        request = wire_sent(ParamGet(1, 0))
        writer.write(request)
        # Answered only once everything ahead of it crossed the line: nothing dropped.
        await asyncio.wait_for(answered(reader, 1), PATIENCE + 3 * sent * 10 / 1e6)
        took = loop.time() - start
        growth = rss_kb(server.proc.pid) - before
        writer.close()
        await writer.wait_closed()
        assert growth < 20_000, f"serve grew {growth} kB taking {sent / 1e6:.1f} MB"
        # The writer was held to the line's rate: it could not get more through than the
        # line carried in the time it took.
        assert (sent + len(request)) * 10 / 1e6 <= took, (sent, took)
        async with await open_when_free(server.url) as link:
            assert await link.get_param("TsTimerPeriod") == 1
        assert await server.stopped(signal.SIGTERM) == 0
        stderr = server.log_text()
    assert "dropped" not in stderr, stderr
    counts = board_counts(stderr)
    assert counts.noise >= sent and counts.held >= 1, counts


async def answered(reader: asyncio.StreamReader, param_id: int) -> None:
    """Until the board's ``PA`` for ``param_id`` comes."""
    wire = b""
    while not any(isinstance(e, ParamAck) and e.param_id == param_id
                  for e in wire_received(wire)):
        data = await reader.read(65536)
        assert data, "the connection closed before the answer"
        wire += data


@pytest.mark.timeout(90)
async def test_clients_that_write_garbage_and_leave_do_not_hold_up_the_next() -> None:
    async with serve("--tcp", "127.0.0.1:0") as server:
        host, port = server.url.removeprefix("socket://").rsplit(":", 1)
        for _ in range(30):
            _, writer = await asyncio.wait_for(connect_when_free(host, int(port)), PATIENCE)
            # A megabyte the line would take 10 s to carry, written and abandoned: the
            # connection is reset with most of it unsent.
            writer.write(os.urandom(1_000_000))
            await asyncio.sleep(0)
            writer.transport.abort()
        # Their bytes are gone with them: the next host is answered within 2 s, where one
        # client's megabyte alone would hold the line for 10 s (100 kB/s at 1 MBd). If serve
        # has not yet seen the last garbage client leave, it tells this one "busy" and closes
        # the connection before the board says anything: a refusal, so connect again.
        refusals = 0
        while True:
            async with await open_when_free(server.url, request_timeout=0.5,
                                            request_tries=4) as link:
                try:
                    assert await link.set_param("TsTimerPeriod", 2) == 2
                    break
                except (BoardLost, LinkClosed):
                    if link.board_alive or refusals >= 20:
                        raise
                    refusals += 1
        assert await server.stopped(signal.SIGTERM) == 0
        stderr = server.log_text()
    assert "Traceback" not in stderr, stderr
    assert board_counts(stderr).discarded > 0, stderr  # what the line had not carried


async def test_a_second_client_is_told_busy_while_the_first_is_connected() -> None:
    async with serve("--tcp", "127.0.0.1:0") as server:
        host, port = server.url.removeprefix("socket://").rsplit(":", 1)
        async with open_link(server.url, reconnect=False) as first:
            assert await first.get_param("TsTimerPeriod") == 1  # the first is being served
            reader, writer = await asyncio.open_connection(host, int(port))
            told = await asyncio.wait_for(reader.read(), PATIENCE)  # then closed: EOF
            writer.close()
            assert told == b"busy: another host is connected\n"
            assert await first.get_param("TsTimerPeriod") == 1
        # Once the first has gone, the port serves the next.
        async with await open_when_free(server.url) as second:
            await wait_until(lambda: second.board_alive, PATIENCE, "the board")
        assert await server.stopped(signal.SIGTERM) == 0
        assert "1 host(s) told busy" in server.log_text()


async def test_a_host_that_sends_nothing_is_let_go_after_the_idle_timeout() -> None:
    # It used to hold the board for ever. A host that has sent something keeps it.
    async with serve("--tcp", "127.0.0.1:0", "--idle-timeout", "0.5") as server:
        host, port = server.url.removeprefix("socket://").rsplit(":", 1)
        reader, writer = await asyncio.open_connection(host, int(port))
        everything = await asyncio.wait_for(reader.read(), PATIENCE)  # until serve closes
        writer.close()
        assert everything.endswith(b"idle: nothing received in 0.5 s; closing\n")
        async with await open_when_free(server.url) as link:
            assert await link.get_param("TsTimerPeriod") == 1
            # Long past the timeout, a host that has spoken is still served.
            await wait_until(lambda: link.stats.alive_received >= 4, PATIENCE,
                             "four E frames (1.2 s)")
            assert await link.get_param("TsTimerPeriod") == 1


# --- fpgaemu's own command line: one line and an exit code, never a traceback -------------------


def fpgaemu(*args: str, timeout: float = 20) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "fpgaemu", *args], capture_output=True,
                          text=True, timeout=timeout)


@pytest.mark.parametrize(
    ("args", "code", "says"),
    [
        (("serve", "--tcp", "::1:0"), 2, "brackets"),
        (("serve", "--tcp", "127.0.0.1:99999"), 2, "HOST:PORT"),
        (("serve", "--tcp", "203.0.113.7:0"), 5, "cannot serve"),
        (("serve", "--pty", "--set", "Kp_Wheel_PidA=1e39"), 2, "float32"),
        (("serve", "--pty", "--set", "TsTimerPeriod=0"), 2, "1..1000"),
        (("serve", "--pty", "--fault", "nonsense"), 2, "fault spec"),
        (("serve", "--pty", "--config", "/nonexistent.toml"), 2, "cannot read"),
        (("serve",), 2, "--pty or --tcp"),
        (("bogus",), 2, "No such command"),
        (("serve", "--robot", "--pty", "--body", "ode"), 2, "choose mujoco or kinematic"),
        (("serve", "--robot", "--pty", "--surface", "ice"), 2, "surface 'ice'"),
        (("serve", "--robot", "--pty", "--body", "mujoco", "--surface", "ideal"), 2,
         "the mujoco body knows"),
        (("serve", "--robot", "--pty", "--body", "kinematic", "--surface", "stairs"), 2,
         "it is flat"),
        (("serve", "--pty", "--body", "mujoco"), 2, "go with --robot"),
        (("serve", "--pty", "--uart-rx", "lvl"), 2, "choose edge or level"),
        (("serve", "--pty", "--tx-gap", "-1"), 2, "--tx-gap"),
    ],
)
def test_bad_input_is_one_line_and_an_exit_code(args: tuple[str, ...], code: int,
                                                says: str) -> None:
    result = fpgaemu(*args)
    assert result.returncode == code, result.stderr
    assert result.stderr.startswith("fpgaemu: error: ") and says in result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr


DEEP_TOML = "x = " + "[" * 20_000 + "]" * 20_000 + "\n"


@pytest.mark.parametrize(("option", "content", "says"), [
    ("--config", DEEP_TOML, "nested too deeply"),
    ("--config", None, "larger than 1 MiB"),  # /dev/zero
    ("--robot-file", DEEP_TOML, "nested too deeply"),
    ("--robot-file", None, "larger than 1 MiB"),
    ("--robot-file", ('surface = "gravel"', 'surface = ["gravel"]'), "surface"),
    ("--robot-file", ('channel = "A"', "channel = {x = 1}"), "channel"),
    ("--robot-file", ('board = "L"', 'board = "L=x y"'), "board name"),
    ("--robot-file", ("y = 0.33", "y = 5e-324"), "wheels.FL.y"),
    ("--robot-file", ("wheel_radius = 0.20", "wheel_radius = 1e-300"), "wheel_radius"),
    ("--config", "", "empty file name"),
    ("--robot-file", "", "empty file name"),
], ids=["config-deep", "config-zero", "robot-deep", "robot-zero", "robot-surface-list",
        "robot-channel-table", "robot-board-name", "robot-track", "robot-radius",
        "config-empty-name", "robot-empty-name"])
def test_a_bad_file_for_serve_is_one_line_exit_2(
        tmp_path: Path, option: str, content: str | tuple[str, str] | None,
        says: str) -> None:
    # Issue 24, items 3–6 and 10: tracebacks (TypeError, RecursionError), memory without
    # bound for /dev/zero, and a robot whose board name broke the ready line.
    from fpgalink.protocol.robot import SEED_ROBOT_TOML

    if content is None:
        where = "/dev/zero"
    elif content == "":
        where = ""
    else:
        path = tmp_path / "file.toml"
        path.write_text(SEED_ROBOT_TOML.replace(*content) if isinstance(content, tuple)
                        else content, encoding="utf-8")
        where = str(path)
    robot = ["--robot"] if option == "--robot-file" else []
    result = fpgaemu("serve", "--pty", *robot, option, where)
    assert result.returncode == 2, result.stderr
    assert result.stderr.startswith("fpgaemu: error: ") and says in result.stderr, \
        result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr


async def test_a_busy_port_is_one_line() -> None:
    async with serve("--tcp", "127.0.0.1:0") as server:
        port = server.url.rsplit(":", 1)[1]
        result = await asyncio.to_thread(fpgaemu, "serve", "--tcp", f"127.0.0.1:{port}")
    assert result.returncode == 5
    assert result.stderr.startswith("fpgaemu: error: cannot serve board L")
    assert result.stderr.count("\n") == 1


async def test_a_board_that_cannot_be_served_leaves_no_ready_line() -> None:
    # N+1 taken: serve used to print `ready L` and then exit, so a script that connected on
    # the first ready line reached a board about to vanish.
    for _attempt in range(5):
        base = free_port_pair()
        with socket.socket() as squatter:
            try:
                squatter.bind(("127.0.0.1", base + 1))
            except OSError:
                continue
            squatter.listen()
            result = await asyncio.to_thread(fpgaemu, "serve", "--tcp", f"127.0.0.1:{base}",
                                             "--boards", "2")
        if "cannot serve board L" in result.stderr:
            continue  # another test took N in the meantime: try anew
        assert result.returncode == 5, result.stderr
        assert result.stderr.startswith("fpgaemu: error: cannot serve board R")
        assert "ready" not in result.stdout
        return
    raise AssertionError("no two free consecutive ports in five attempts")


def test_version_and_help_before_the_command() -> None:
    assert fpgaemu("--version").stdout.startswith("fpgaemu, version ")
    assert "serve" in fpgaemu("-h").stdout
    assert "--link" in fpgaemu("serve", "-h").stdout


@pytest.mark.timeout(60)
async def test_a_parameter_dump_serves_as_a_config(tmp_path: Path) -> None:
    # `param dump` wrote a file `serve --config` refused ("unknown parameter 'A'").
    dump = tmp_path / "params.toml"
    async with serve("--pty", "--set", "Kp_Wheel_PidB=7.11") as server:
        result = await asyncio.to_thread(subprocess.run, [
            sys.executable, "-m", "fpgalink", "param", "dump", str(dump),
            "--port", server.url], capture_output=True, text=True, timeout=30)
        assert result.returncode == 0, result.stderr
    assert "[A]" in dump.read_text() and "[B]" in dump.read_text()
    async with serve("--pty", "--config", str(dump)) as server, \
            open_link(server.url) as link:
        assert await link.get_param("Kp_Wheel_PidB") == pytest.approx(7.11)


async def test_links_name_each_pty_stably_and_go_on_exit(tmp_path: Path) -> None:
    left, right = tmp_path / "fpga-L", tmp_path / "fpga-R"
    async with serve("--pty", "--boards", "2", "--link", f"L={left}", "--link",
                     f"R={right}") as server:
        assert server.ready == {"L": str(left), "R": str(right)}
        for name, path in (("L", left), ("R", right)):
            assert path.is_symlink() and os.readlink(path) == server.ptys[name]
        async with open_link(str(left)) as link:  # the link path is a working port
            await wait_until(lambda: link.stats.alive_received >= 1, PATIENCE, "an E frame")
        assert await server.stopped(signal.SIGTERM) == 0
    assert not left.exists() and not left.is_symlink() and not right.is_symlink()


async def test_a_link_never_replaces_a_file(tmp_path: Path) -> None:
    precious = tmp_path / "notes.txt"
    precious.write_text("mine")
    result = await asyncio.to_thread(fpgaemu, "serve", "--pty", "--link", str(precious))
    assert result.returncode == 5
    assert result.stderr.startswith("fpgaemu: error: --link") and "not a symlink" in result.stderr
    assert precious.read_text() == "mine"


async def test_tcp_ports_are_reported_as_they_are() -> None:
    # Port 0: every board gets its own free port, and the ready lines say which.
    async with serve("--tcp", "127.0.0.1:0", "--boards", "2") as server:
        ports = [int(url.rsplit(":", 1)[1]) for url in server.ready.values()]
        assert len(set(ports)) == 2 and 0 not in ports
        for url in server.ready.values():
            link = await open_when_free(url)
            try:
                await wait_until(lambda lk=link: lk.stats.alive_received >= 1,  # type: ignore[misc]
                                 PATIENCE, "an E frame")
            finally:
                await link.close()
    # Port N: boards take N, N+1. Another test's connection can take N+1 between the probe
    # and serve's bind (a CI run hit it); serve then says so and exits, and we try anew.
    for _attempt in range(5):
        base = free_port_pair()
        try:
            async with serve("--tcp", f"127.0.0.1:{base}", "--boards", "2") as server:
                assert list(server.ready.values()) == [f"socket://127.0.0.1:{base}",
                                                       f"socket://127.0.0.1:{base + 1}"]
                return
        except ServeExited as exc:
            assert "address already in use" in str(exc), exc
    raise AssertionError("no two free consecutive ports in five attempts")


def free_port_pair() -> int:
    """A port N such that N and N+1 were both free a moment ago."""
    while True:
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            base: int = probe.getsockname()[1]
            if base == 65535:
                continue
            with socket.socket() as second:
                try:
                    second.bind(("127.0.0.1", base + 1))
                except OSError:
                    continue
                return base


def test_options_before_serve_and_after_it() -> None:
    result = fpgaemu("--tcp", "127.0.0.1:0", "serve", "--pty")
    assert result.returncode == 2  # both given: the one after does not silently win
    assert "exactly one of --pty or --tcp" in result.stderr


def test_options_before_serve_are_honoured() -> None:
    with served(command=(sys.executable, "-m", "fpgaemu", "--pty", "--boards", "2")) as server:
        lines = server.lines
        assert [li[:2] for li in lines] == [["ready", "L"], ["ready", "R"]], lines
        assert all(li[2].startswith("/dev/pts/") for li in lines)
        assert server.stop() == 0
