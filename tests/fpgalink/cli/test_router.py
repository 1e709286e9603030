"""``fpgalink-cli router`` (issue 26): an emulated robot's two boards shared by one
controller (``drive``) and two observers (``record --passive``), every observer seeing
every ``TM`` of the controller's run; an observer's writes refused and counted; the board
disabled when its controller goes; the accounting exact per client."""

from __future__ import annotations

import functools
import itertools
import json
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from tests.fpgalink.cli.test_errors import assert_one_line_error
from tests.support.cli import CLI, ROOT, cli_env
from tests.support.serving import Served, served, start_serve
from tests.support.waiting import wait_until_sync

pytestmark = pytest.mark.timeout(180)

_SCRIPT = Path(sys.executable).parent / "fpgalink-cli"
SCRIPT = [str(_SCRIPT)] if _SCRIPT.exists() else CLI


class Router:
    def __init__(self, tmp_path: Path, *args: str) -> None:
        self.err_path = tmp_path / "router.err"
        self.err = self.err_path.open("w")
        self.proc = subprocess.Popen([*SCRIPT, "router", "--format", "json", *args],
                                     stdout=subprocess.PIPE, stderr=self.err, text=True,
                                     cwd=ROOT, env=cli_env())
        assert self.proc.stdout is not None
        self.urls: dict[str, str] = {}
        while len(self.urls) < args.count("--port"):
            line = self.proc.stdout.readline()
            assert line.startswith("ready "), (line, self.stderr())
            _, name, url = line.split()
            self.urls[name] = url

    def ports(self) -> list[str]:
        return [a for name, url in self.urls.items() for a in ("--port", f"{name}={url}")]

    def stderr(self) -> str:
        return self.err_path.read_text()

    def stop(self) -> dict[str, Any]:
        self.proc.send_signal(signal.SIGINT)
        out, _ = self.proc.communicate(timeout=30)
        self.err.close()
        assert self.proc.returncode == 0, self.stderr()
        assert "Traceback" not in self.stderr()
        summary: dict[str, Any] = json.loads(out)
        return summary

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self.err.close()


@pytest.fixture
def robot_router(tmp_path: Path) -> Iterator[Router]:
    query = "surface=ideal"
    router = Router(tmp_path, "--port", f"L=emu://robot/L?{query}",
                    "--port", f"R=emu://robot/R?{query}")
    yield router
    router.kill()


def _tm_counters(path: Path, topic: str) -> list[int]:
    with path.open("rb") as f:
        return [json.loads(m.data)["counter"] for _, _, m in
                make_reader(f).iter_messages(topics=[topic])]


def test_two_observers_see_every_tm_of_the_controllers_run(robot_router: Router,
                                                           tmp_path: Path) -> None:
    router = robot_router
    observers = [subprocess.Popen(
        [*SCRIPT, "record", "--passive", str(tmp_path / f"observer{i}.mcap"), "--duration",
         "25", *router.ports()], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        cwd=ROOT, env=cli_env()) for i in (1, 2)]
    try:
        wait_until_sync(lambda: router.stderr().count("client #2 connected") == 2, 30,
                        "both observers on both boards")
        controller = tmp_path / "controller.mcap"
        drive = subprocess.run([*SCRIPT, "drive", "--v", "0.1", "--for", "1", "--record",
                                str(controller), *router.ports()], capture_output=True,
                               text=True, cwd=ROOT, env=cli_env(), timeout=60)
        # Through the router's process a loaded machine may stop the drive for real (the
        # router or this host not scheduled in time: a board's telemetry late, a watchdog
        # lapsed): said, exit 7, its recording complete up to there. What is checked holds
        # either way: every TM the controller got, each observer got too.
        assert drive.returncode == 0 or (
            drive.returncode == 7 and "the robot was stopped: " in drive.stderr), drive.stderr
        for observer in observers:
            _, err = observer.communicate(timeout=60)  # its --duration: it reads to the end
            assert observer.returncode == 0, err
    finally:
        for observer in observers:
            if observer.poll() is None:
                observer.kill()
    summary = router.stop()
    for board in ("L", "R"):
        driven = _tm_counters(controller, f"/board/{board}/telemetry")
        assert len(driven) > 100
        for i in (1, 2):
            seen = set(_tm_counters(tmp_path / f"observer{i}.mcap", f"/board/{board}/telemetry"))
            assert set(driven) <= seen, f"observer {i} missed TMs of board {board}"
    clients = summary["clients"]
    assert isinstance(clients, list)
    for board in ("L", "R"):
        mine = {c["client"]: c for c in clients if c["board"] == board}
        assert mine[1]["role"] == mine[2]["role"] == "observer"
        controller_stats = mine[max(mine)]  # the drive (the last one, if it was run again)
        assert controller_stats["role"] == "controller"
        assert controller_stats["frames_to_board"] > 0
        for stats in mine.values():
            assert stats["dropped_frames"] == 0 and stats["refused_frames"] == 0
        # The observers, connected before and after the run, got at least what it got.
        assert mine[1]["frames_to_client"] > controller_stats["frames_to_client"]


def test_an_observers_writes_are_refused_and_counted(tmp_path: Path) -> None:
    router = Router(tmp_path, "--port", "emu://")
    try:
        (url,) = router.urls.values()
        controller = subprocess.Popen([*SCRIPT, "monitor", "--duration", "20", "--format",
                                       "jsonl", "--port", url], stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True, cwd=ROOT, env=cli_env())
        try:
            wait_until_sync(lambda: "is the controller" in router.stderr(), 30, "a controller")
            # An observer that tries to enable the board and to set a parameter.
            # (It stays a while: a client that closes with frames unread resets the
            # connection, and the kernel may then discard what it sent last, unread.)
            enable = subprocess.run([*SCRIPT, "send", "RE", "--reply", "PA", "--wait", "2",
                                     "--port", url], capture_output=True, text=True,
                                    cwd=ROOT, env=cli_env(), timeout=60)
            assert enable.returncode == 4, enable.stderr  # no PA: nothing reached the board
            refused = subprocess.run([*SCRIPT, "--retries", "2", "param", "set",
                                      "TsTimerPeriod", "5", "--port", url],
                                     capture_output=True, text=True, cwd=ROOT,
                                     env=cli_env(), timeout=60)
            # Told, in words (issue 41): the router answered its PS with PN 5.
            assert refused.returncode == 3, refused.stderr
            assert_one_line_error(refused.stderr, "refused by the router: another client "
                                  "controls the board")
            assert "is an observer" in router.stderr()
        finally:
            controller.send_signal(signal.SIGINT)
            controller.communicate(timeout=30)
        summary = router.stop()
    finally:
        router.kill()
    clients = {c["client"]: c for c in summary["clients"]}
    assert clients[1]["role"] == "controller" and clients[1]["refused_frames"] == 0
    assert clients[2]["refused_by_id"] == {"RE": 1} and clients[2]["frames_to_board"] == 0
    # The PN is final: not sent again. Before it, the command asked who the board is: its
    # IQ passed to the board (a question), the PG after it refused as every read is.
    assert clients[3]["refused_by_id"] == {"PG": 1, "PS": 1}
    assert clients[3]["to_board_by_id"] == {"IQ": 1}


def test_the_board_is_disabled_when_its_controller_goes(tmp_path: Path) -> None:
    router = Router(tmp_path, "--port", "emu://")
    try:
        (url,) = router.urls.values()
        # A controller that enables the board and is killed (no RD of its own).
        code = ("import asyncio, os, signal\n"
                "from fpgalink.aio.link import open_link\n"
                "async def main():\n"
                f"    async with open_link({url!r}) as link:\n"
                "        await link.set_param('GetDataPeriodical', 1)\n"
                "        link.enable()\n"
                "        async for tm in link.telemetry():\n"
                "            if tm.a.flags & 1:\n"
                "                print('enabled', flush=True)\n"
                "                os.kill(os.getpid(), signal.SIGKILL)\n"
                "asyncio.run(main())\n")
        killed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                cwd=ROOT, env=cli_env(), timeout=60)
        assert killed.stdout == "enabled\n", killed.stderr
        # The next client sees the board disabled at once, well before its 300 ms watchdog
        # would have: the router sent RD when the controller's connection closed.
        watch = ("import asyncio\n"
                 "from fpgalink.aio.link import open_link\n"
                 "async def main():\n"
                 f"    async with open_link({url!r}) as link:\n"
                 "        await link.set_param('GetDataPeriodical', 1)\n"
                 "        tm = await anext(aiter(link.telemetry()))\n"
                 "        print(tm.a.flags & 1)\n"
                 "asyncio.run(main())\n")
        seen = subprocess.run([sys.executable, "-c", watch], capture_output=True, text=True,
                              cwd=ROOT, env=cli_env(), timeout=60)
        assert seen.stdout == "0\n", seen.stderr
        assert "client #1 (controller) left" in router.stderr()
        summary = router.stop()
    finally:
        router.kill()
    (board,) = summary["boards"]
    assert board["disables_sent"] == 2  # one per controller that left: killed, then watcher


def _whole_lines(text: str) -> list[str]:
    """The lines of a file a live process is writing: whole lines only (it may be writing
    the last one)."""
    return text[:text.rfind("\n") + 1].splitlines()


def _counters(text: str) -> list[int]:
    return [json.loads(line)["counter"] for line in _whole_lines(text)
            if line.startswith("{") and '"counter"' in line]


def test_a_pty_observer_sees_every_tm_of_a_tcp_controller(tmp_path: Path) -> None:
    router = Router(tmp_path, "--pty", "1", "--port", "emu://")
    observed = tmp_path / "observer.jsonl"
    try:
        assert router.urls  # the TCP endpoint; the pty's ready line follows it
        assert router.proc.stdout is not None
        _, _, pty = router.proc.stdout.readline().split()
        with observed.open("w") as out:
            observer = subprocess.Popen([*SCRIPT, "monitor", "--passive", "--format", "jsonl",
                                         "--port", pty], stdout=out, stderr=subprocess.PIPE,
                                        text=True, cwd=ROOT, env=cli_env())
        try:
            wait_until_sync(lambda: "client #1 connected (/dev/" in router.stderr(), 30,
                            "the observer on the pty")
            (url,) = router.urls.values()
            controller = subprocess.run([*SCRIPT, "monitor", "--duration", "1", "--format",
                                         "jsonl", "--port", url], capture_output=True,
                                        text=True, cwd=ROOT, env=cli_env(), timeout=60)
            assert controller.returncode == 0, controller.stderr
            driven = _counters(controller.stdout)
            assert len(driven) > 200
            # The observer writes each sample as it reads it: wait until it has the last.
            wait_until_sync(lambda: max(driven) in _counters(observed.read_text()), 30,
                            "the observer to read the controller's last TM")
        finally:
            observer.send_signal(signal.SIGINT)
            observer.communicate(timeout=30)
        summary = router.stop()
    finally:
        router.kill()
    assert set(driven) <= set(_counters(observed.read_text()))
    clients = {c["client"]: c for c in summary["clients"]}
    assert clients[1]["peer"].startswith("/dev/") and clients[1]["role"] == "observer"
    assert clients[1]["dropped_frames"] == 0 and clients[2]["role"] == "controller"


def test_a_client_that_does_not_read_loses_frames_alone_and_counted(tmp_path: Path) -> None:
    import socket

    router = Router(tmp_path, "--client-buffer", "4096", "--port", "emu://")
    try:
        (url,) = router.urls.values()
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        stuck = socket.socket()  # connects, never reads (a small window: little in flight)
        stuck.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stuck.connect((host, int(port)))
        try:
            wait_until_sync(lambda: "client #1 connected" in router.stderr(), 30, "it")
            controller = subprocess.run([*SCRIPT, "monitor", "--duration", "2", "--format",
                                         "jsonl", "--port", url], capture_output=True,
                                        text=True, cwd=ROOT, env=cli_env(), timeout=60)
            assert controller.returncode == 0, controller.stderr
            summary = router.stop()
        finally:
            stuck.close()
    finally:
        router.kill()
    clients = {c["client"]: c for c in summary["clients"]}
    # The one that does not read: whole frames dropped once its buffer was full, and every
    # frame of the controller's run accounted for (delivered or dropped); the controller
    # lost nothing.
    assert clients[1]["dropped_frames"] > 100
    assert (clients[1]["frames_to_client"] + clients[1]["dropped_frames"]
            >= clients[2]["frames_to_client"])
    assert clients[2]["role"] == "controller" and clients[2]["dropped_frames"] == 0
    assert len(_counters(controller.stdout)) > 500


def _said(router: Router, what: str) -> bool:
    return what in router.stderr()


@pytest.mark.parametrize("kind", ["pty", "tcp"])
def test_a_board_unplugged_and_back_is_reopened_with_its_clients_kept(
        tmp_path: Path, kind: str) -> None:
    """``fpgaemu serve --fault unplug``: the board's pty goes and comes back behind its
    symlink, or its TCP port stops listening and listens again. The router reopens it; its
    clients (a controller on the router's own --link pty, an observer over TCP) stay
    connected, see the silence, and get every frame again after it, the observer every TM
    the controller got."""
    board_link, client_link = tmp_path / "fpga0", tmp_path / "router0"
    # Unplugged 6 s into the board's life, for 1 s: after the router has opened it.
    if kind == "pty":
        serve = start_serve("--pty", "--link", str(board_link), "--fault", "unplug=6:1")
        board = str(board_link)
    else:
        serve = start_serve("--tcp", "127.0.0.1:0", "--fault", "unplug=6:1")
        board = serve.url
    router = None
    try:
        router = Router(tmp_path, "--link", str(client_link), "--port", board)
        assert router.proc.stdout is not None
        ready = router.proc.stdout.readline().split()
        assert ready[:4] == ["ready", "0", str(client_link), "->"], ready
        assert client_link.is_symlink()
        outputs = {role: tmp_path / f"{role}.jsonl" for role in ("controller", "observer")}
        clients: dict[str, subprocess.Popen[str]] = {}
        # The observer is connected before the controller asks for telemetry.
        for role, args, sign in (
                ("observer", ["--passive", "--port", router.urls["0"]], "client #1 connected"),
                ("controller", ["--port", str(client_link)], "is the controller")):
            with outputs[role].open("w") as out:
                clients[role] = subprocess.Popen(
                    [*SCRIPT, "monitor", "--format", "jsonl", *args], stdout=out,
                    stderr=subprocess.PIPE, text=True, cwd=ROOT, env=cli_env())
            wait_until_sync(functools.partial(_said, router, sign), 30, f"the {role}")
        try:
            wait_until_sync(lambda: "back after" in router.stderr(), 60,
                            f"the port back: {router.stderr()}")
            after = len(_counters(outputs["controller"].read_text()))
            wait_until_sync(lambda: len(_counters(outputs["controller"].read_text()))
                            > after + 200, 30, "the controller's TMs after the replug")
            clients["controller"].send_signal(signal.SIGINT)
            clients["controller"].communicate(timeout=30)
            last = max(_counters(outputs["controller"].read_text()))
            # The observer writes each sample as it reads it: wait until it has the last.
            wait_until_sync(lambda: last in _counters(outputs["observer"].read_text()), 30,
                            "the observer to read the controller's last TM")
        finally:
            for client in clients.values():
                if client.poll() is None:
                    client.send_signal(signal.SIGINT)
                    client.communicate(timeout=30)
        summary = router.stop()
    finally:
        if router is not None:
            router.kill()
        serve.stop()
    assert not client_link.exists()  # its symlink goes with the router
    (board,) = summary["boards"]
    assert board["port_losses"] == 1 and board["reconnects"] == 1
    driven = _counters(outputs["controller"].read_text())
    # The unplugged second is one long gap in the counters, telemetry before and after it.
    # (A TM the emulated board itself drops, its TX queue full, is a gap of a few.)
    gaps = [(a, b) for a, b in itertools.pairwise(driven) if b - a > 500]
    assert len(gaps) == 1, gaps
    assert driven.index(gaps[0][1]) < len(driven) - 200
    assert set(driven) <= set(_counters(outputs["observer"].read_text()))
    stats = {c["role"]: c for c in summary["clients"]}
    assert stats["controller"]["peer"].startswith(f"{client_link} -> /dev/")
    assert stats["controller"]["dropped_frames"] == stats["observer"]["dropped_frames"] == 0
    # An observer's link may ask the board heard again after the silence whether it
    # restarted: refused, as anything it sends; nothing of it reaches the board.
    assert stats["observer"]["frames_to_board"] == 0, stats["observer"]


def test_with_no_reconnect_a_port_that_goes_stops_the_router(tmp_path: Path) -> None:
    with served("--pty") as serve:
        router = Router(tmp_path, "--no-reconnect", "--port", serve.url)
        try:
            serve.stop()  # the board's pty goes with its server
            router.proc.communicate(timeout=30)
            router.err.close()
        finally:
            router.kill()
    assert router.proc.returncode == 5, router.stderr()
    assert f"its port {serve.url} closed: the router stops" in router.stderr()


@pytest.mark.parametrize(("links", "needle"), [
    (["X=/tmp/nowhere"], "no board named 'X'"),
    (["{tmp}/file"], "exists and is not a symlink"),
    (["{tmp}/a", "0={tmp}/a"], "the same path twice"),
])
def test_bad_links_are_one_line_exit_2(links: list[str], needle: str, tmp_path: Path) -> None:
    (tmp_path / "file").write_text("mine\n")
    args = [a for link in links for a in ("--link", link.format(tmp=tmp_path))]
    done = subprocess.run([*SCRIPT, "router", *args, "--port", "emu://"], capture_output=True,
                          text=True, cwd=ROOT, env=cli_env(), timeout=60)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, needle)
    assert (tmp_path / "file").read_text() == "mine\n"


def _enabled_or_gone(router: Router, command: subprocess.Popen[str], client: str) -> bool:
    return command.poll() is not None or router.stderr().count(f"{client} RE") == 2


@pytest.mark.parametrize("command", [["drive", "--v", "0.05", "--for", "120"],
                                     ["goto", "5", "0", "--time-limit", "120"]])
def test_sigterm_stops_a_robot_command_that_disables_both_boards_first(
        tmp_path: Path, command: list[str]) -> None:
    """SIGTERM as Ctrl-C (issue 26): the router, between the command and the boards, says
    what the command itself sends each board (-v) — its own RD before it left, not the one
    the router sends for a controller that goes."""
    query = "surface=ideal"
    router = Router(tmp_path, "-v", "--port", f"L=emu://robot/L?{query}",
                    "--port", f"R=emu://robot/R?{query}")
    try:
        # The command must have reached what is tested (both boards enabled) before its
        # SIGTERM: one that a loaded machine's fault stopped while it started (said, exit
        # 7) tested nothing, and is started again. Its outcome is never run again.
        for attempt in range(1, 4):
            driving = subprocess.Popen([*SCRIPT, *command, *router.ports()],
                                       stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                       text=True, cwd=ROOT, env=cli_env())
            client = f"client #{attempt} sent"
            try:
                wait_until_sync(functools.partial(_enabled_or_gone, router, driving, client),
                                60, "both boards enabled")
                driving.send_signal(signal.SIGTERM)
                _, err = driving.communicate(timeout=30)
            finally:
                if driving.poll() is None:
                    driving.kill()
            if router.stderr().count(f"{client} RE") >= 2:
                break
            assert driving.returncode == 7 and "the robot was stopped: " in err, err
        assert driving.returncode == 143, err
        assert "Traceback" not in err
        # Its RD came from it, before it left.
        said = router.stderr()
        for board in ("L", "R"):
            disabled = said.index(f"board {board}: {client} RD")
            assert disabled < said.index(f"board {board}: client #{attempt} (controller) left")
        summary = router.stop()
    finally:
        router.kill()
    for board in ("L", "R"):
        (stats,) = [c for c in summary["clients"]
                    if c["board"] == board and c["client"] == attempt]
        assert stats["to_board_by_id"]["RD"] >= 1, stats


class _Wire:
    """A board's port that takes what the router writes (an ``asyncio.WriteTransport``)."""

    def __init__(self) -> None:
        import asyncio

        class Transport(asyncio.WriteTransport):
            def __init__(self, sink: list[bytes]) -> None:
                super().__init__()
                self.sink = sink

            def write(self, data: bytes | bytearray | memoryview) -> None:
                self.sink.append(bytes(data))

            def is_closing(self) -> bool:
                return False

        self.written: list[bytes] = []
        self.transport = Transport(self.written)


async def test_rd_goes_first_when_the_port_is_back_even_with_a_new_controller(
        capsys: pytest.CaptureFixture[str]) -> None:
    """The controller leaves while the board's port is gone and another client takes over
    before it is back: the RD the first one was owed goes to the board first (the board
    may still be enabled, an outage shorter than its watchdog), then the new controller's
    frames. Before, a new controller cancelled it: the motor stayed driven."""
    from fpgalink.protocol.framing import encode_frame
    from fpgalink.router import DISABLE, BoardRoute, ClientStats

    class Client:
        def __init__(self) -> None:
            self.stats = ClientStats(0, "test")

    route = BoardRoute("L", "emu://", 1 << 16)
    wire = _Wire()
    route.board = wire.transport
    first: Any = Client()
    second: Any = Client()
    route.joined(first, "first")
    route.joined(second, "second")
    route.from_client(first, [b"RE"])
    assert wire.written == [encode_frame(b"RE")]
    route.port_lost(None)
    route.left(first)
    assert route.disable_pending and route.disables_sent == 0
    route.from_client(second, [b"RE"])  # the port is gone: unsent
    assert second.stats.unsent_frames == 1
    assert route.controller is second
    route.board = wire.transport
    route.port_back(1)
    assert wire.written[1:] == [DISABLE]
    assert route.disables_sent == 1 and not route.disable_pending
    route.from_client(second, [b"RE"])
    assert wire.written[2:] == [encode_frame(b"RE")]
    assert "RD sent for the controller that left while the port was gone" in (
        capsys.readouterr().err)


def test_bad_link_refused_through_the_console_script(tmp_path: Path) -> None:
    import os

    master, slave = os.openpty()
    try:
        link = tmp_path / "taken"
        link.symlink_to(os.ttyname(slave))
        done = subprocess.run([*SCRIPT, "router", "--link", str(link), "--port", "emu://"],
                              capture_output=True, text=True, cwd=ROOT, env=cli_env(),
                              timeout=60)
        assert done.returncode == 2, done.stderr
        assert_one_line_error(done.stderr, "another router or fpgaemu serve")
        assert os.readlink(link) == os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


# --- issue 37: floods toward the board; issue 41: a refusal said ---------------------------


def _serve(kind: str) -> Served:
    """``fpgaemu serve`` (``pty`` or ``tcp``) streaming telemetry from power-up (its log has
    the accounting it prints when it stops)."""
    where = ["--pty"] if kind == "pty" else ["--tcp", "127.0.0.1:0"]
    return start_serve(*where, "--set", "GetDataPeriodical=1")


def _stop(observer: subprocess.Popen[str] | None, router: Router | None,
          serve: Served) -> int:
    """Stop what a flood test started; what the board's line received from the host."""
    if observer is not None:
        observer.kill()
        observer.communicate(timeout=30)
    if router is not None:
        router.kill()
    return _host_bytes_the_board_got(serve)


def _host_bytes_the_board_got(serve: Served) -> int:
    """Stop serve; what its board's line received from the host (its own count)."""
    import re

    serve.stop(signal.SIGINT, timeout=30)
    found = re.search(r"host → board ([\d,]+) bytes", serve.log_text())
    assert found, serve.log_text()
    return int(found.group(1).replace(",", ""))


def _samples(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in _whole_lines(path.read_text())
            if line.startswith("{") and '"t_us"' in line]


def _observer(router: Router, out: Path) -> subprocess.Popen[str]:
    with out.open("w") as stdout:
        proc = subprocess.Popen([*SCRIPT, "monitor", "--passive", "--format", "jsonl",
                                 *router.ports()], stdout=stdout, stderr=subprocess.PIPE,
                                text=True, cwd=ROOT, env=cli_env())
    wait_until_sync(lambda: "client #1 connected" in router.stderr(), 30, "the observer")
    return proc


def _flooder(router: Router) -> Any:
    import socket

    host, port = router.urls["L"].removeprefix("socket://").rsplit(":", 1)
    flooder = socket.create_connection((host, int(port)))
    wait_until_sync(lambda: "client #2 connected" in router.stderr(), 30, "the flooder")
    return flooder


def test_one_burst_does_not_freeze_the_router(tmp_path: Path) -> None:
    """Issue 37.1: a client's burst of 100,000 RE toward a board on a pty. Before, the
    router queued each frame in pyserial-asyncio's transport, which summed its whole
    buffer at every write: minutes of a frozen router, no observer served, SIGTERM
    unheard. Now the router goes on serving its observer, stops on SIGTERM, and every one
    of the burst's frames is accounted for: passed to the board (the board's own count
    agrees), refused for a full line, or dropped behind the RD it sent when it stopped."""
    observed = tmp_path / "observer.jsonl"
    serve = _serve("pty")
    board = serve.url
    router = observer = None
    try:
        router = Router(tmp_path, "--port", f"L={board}")
        observer = _observer(router, observed)
        wait_until_sync(lambda: len(_samples(observed)) > 100, 30, "the observer's TMs")
        flooder = _flooder(router)
        try:
            flooder.sendall(b"SREP" * 100_000)
            before = len(_samples(observed))
            wait_until_sync(lambda: len(_samples(observed)) > before + 500, 60,
                            "the observer served through the burst")
            router.proc.send_signal(signal.SIGTERM)
            out, _ = router.proc.communicate(timeout=30)
        finally:
            flooder.close()
        assert router.proc.returncode == 0, router.stderr()
        summary = json.loads(out)
    finally:
        got = _stop(observer, router, serve)
    clients = {c["client"]: c for c in summary["clients"]}
    burst = clients[2]
    assert burst["role"] == "controller" and burst["to_board_by_id"].keys() <= {"RE"}
    passed = burst["frames_to_board"]
    assert passed + burst["line_full_frames"] + burst["overtaken_frames"] == 100_000, burst
    assert burst["line_full_frames"] > 0  # it wrote 4 s of line time at once
    assert got == 4 * passed + 4  # the board got exactly those, and the router's RD
    assert clients[1]["dropped_frames"] == 0 and clients[1]["refused_frames"] == 0


def test_a_flooding_controller_that_leaves_is_overtaken_by_the_rd(tmp_path: Path) -> None:
    """Issue 37.2: a controller writes 10 s of line time (250,000 RE) toward a TCP board
    and leaves. Before, the router had handed it all to the port, and its RD came after
    it: the board stayed enabled for 10 s. Now at most BOARD_QUEUE_S of line time waits
    for the board; the RD goes ahead of the departed client's queued frames, which are
    dropped and counted. Checked on the board: its line received exactly what the router
    says it passed, then the RD (so nothing of the departed client came after it); its
    telemetry (board time) shows it enabled for no longer than the client was connected,
    plus the margin of a loaded machine."""
    import socket
    import time

    observed = tmp_path / "observer.jsonl"
    serve = _serve("tcp")
    board = serve.url
    router = observer = None
    try:
        router = Router(tmp_path, "--port", f"L={board}")
        observer = _observer(router, observed)
        flooder = _flooder(router)
        began = time.monotonic()
        try:
            flooder.sendall(b"SREP" * 250_000)
            flooder.shutdown(socket.SHUT_WR)  # then read until the router lets it go
            flooder.settimeout(60)
            while flooder.recv(65536):
                pass
            flood_s = time.monotonic() - began  # it sent, and the router let it go
        finally:
            flooder.close()
        wait_until_sync(lambda: "client #2 (controller) left" in router.stderr(), 30, "it")

        def settled() -> bool:
            # Disabled for 300 TMs (300 ms of board time) after it was last enabled: a
            # watchdog lapse while the flood came (a loaded machine's stall between two
            # handed frames) was followed by the next RE; nothing follows the RD.
            enabled = [s["a_flags"] & 1 for s in _samples(observed)]
            return 1 in enabled and enabled[::-1].index(1) > 300

        wait_until_sync(settled, 60, "the board disabled for good")
        summary = router.stop()
    finally:
        got = _stop(observer, router, serve)
    samples = _samples(observed)
    enabled = [s["a_flags"] & 1 for s in samples]
    on = enabled.index(1)
    off = len(enabled) - enabled[::-1].index(1)  # the first TM after the last enabled one
    enabled_s = (samples[off]["t_us"] - samples[on]["t_us"]) / 1e6
    assert enabled_s <= flood_s + 2.0, (enabled_s, flood_s)  # was 10 s
    from fpgalink.router import BOARD_QUEUE_S

    flood = {c["client"]: c for c in summary["clients"]}[2]
    passed = flood["frames_to_board"]
    assert passed + flood["line_full_frames"] + flood["overtaken_frames"] == 250_000, flood
    # What went to the board is bounded by the line's time while it was connected.
    assert 4 * passed <= (flood["connected_s"] + BOARD_QUEUE_S) * 100_000, flood
    assert got == 4 * passed + 4  # its frames the router passed, then the RD: no more
    assert summary["boards"][0]["disables_sent"] == 1

def test_a_refused_parameter_set_says_the_router_refused_it(tmp_path: Path) -> None:
    """Issue 41.4: while another client controls the board through the router, a client's
    ``param set`` was "board not answering … no answer after 8 tries", exit 4, the reason
    only on the router's stderr. The router answers a non-controller's PS with PN 5: exit
    3, one line saying the router refused it and why, and the board untouched. (The
    controller here is a plain socket that sent one RD: a driving command would do, but a
    loaded machine can stop one before the refusal is tried.)"""
    import socket

    router = Router(tmp_path, "--port", "L=emu://")
    try:
        host, port = router.urls["L"].removeprefix("socket://").rsplit(":", 1)
        with socket.create_connection((host, int(port))) as controller:
            controller.sendall(b"SRDP")
            wait_until_sync(lambda: "client #1 (" in router.stderr(), 30, "the controller")
            refused = subprocess.run([*SCRIPT, "param", "set", "Kp_Wheel_PidA", "500",
                                      "--port", router.urls["L"]], capture_output=True,
                                     text=True, cwd=ROOT, env=cli_env(), timeout=60)
            answer = _answer_to_a_crc_request(host, int(port))
        wait_until_sync(lambda: "client #1 (controller) left" in router.stderr(), 30, "it")
        untouched = subprocess.run([*SCRIPT, "param", "get", "Kp_Wheel_PidA", "--port",
                                    router.urls["L"]], capture_output=True, text=True,
                                   cwd=ROOT, env=cli_env(), timeout=60)
        summary = router.stop()
    finally:
        router.kill()
    assert refused.returncode == 3, refused.stderr
    assert_one_line_error(refused.stderr, "Kp_Wheel_PidA on channel A refused by the "
                          "router: another client controls the board", "--passive")
    assert untouched.returncode == 0 and float(untouched.stdout.split()[-1]) != 500, (
        untouched.stdout, untouched.stderr)
    clients = {c["client"]: c for c in summary["clients"]}
    assert clients[2]["role"] == "observer"
    assert clients[2]["refused_by_id"] == {"PG": 1, "PS": 1}  # the identity's PG too
    # A client with the wire CRC on is answered with it (docs/protocol.md §7), else its
    # link would drop the answer as a CRC failure.
    from fpgalink.protocol import NackReason, ParamNack, parse_content
    from fpgalink.protocol.crc import strip_crc

    body = strip_crc(answer)
    assert body is not None, answer
    assert parse_content(body) == ParamNack(1, 0, NackReason.NOT_CONTROLLER, 0)
    assert clients[3]["refused_by_id"] == {"PG": 1}


def _answer_to_a_crc_request(host: str, port: int) -> bytes:
    """A raw client's ``PG TsTimerPeriod`` with the wire CRC, and the content of the first
    ``PN`` it gets back."""
    import socket

    from fpgalink.protocol import DEFAULT_FRAMING, FrameDecoder, ParamGet, encode_frame
    from fpgalink.protocol import encode_message as encode
    from fpgalink.protocol.crc import append_crc

    with socket.create_connection((host, port)) as client:
        client.sendall(encode_frame(append_crc(encode(ParamGet(1, 0), 0)), DEFAULT_FRAMING))
        client.settimeout(30)
        decoder = FrameDecoder()
        while True:
            data = client.recv(65536)
            assert data, "closed before an answer"
            for item in decoder.feed(data):
                if isinstance(item, bytes) and item[:2] == b"PN":
                    return item


async def test_the_line_queue_paces_bounds_and_is_overtaken_by_a_disable() -> None:
    """LineQueue on its own, time passed in: frames go to the port only while what went
    before has less than the lead left on the line; beyond the bound they are refused; a
    disable goes ahead of what waits, which is dropped and returned."""
    from fpgalink.router import LineQueue

    line: LineQueue[int] = LineQueue(1_000_000, bound=0.01, lead=0.002)  # 1,000 / 200 B
    assert all(line.push(i, 100, 0.0) for i in range(10))
    assert not line.push(10, 100, 0.0)  # 1,000 bytes wait: full
    assert line.take(0.0) == [0, 1]  # 200 bytes of lead
    assert line.take(0.0) == []  # the lead is on its way
    assert line.wake_at() == pytest.approx(0.001)
    assert line.take(0.001) == [2]  # 1 ms to go: 100 bytes more
    assert line.backlog(0.001) == pytest.approx(0.009)
    assert line.push(10, 100, 0.001)  # room again, 100 bytes gone
    assert line.overtake(4, 0.001) == [3, 4, 5, 6, 7, 8, 9, 10]
    assert len(line) == 0 and line.wake_at() is None
    assert line.in_flight(0.001) == pytest.approx(0.002 + 4e-5)


def test_the_routers_refusal_is_no_part_of_the_boards_counter_sequence() -> None:
    """The router's PN 5 carries its own counter toward the client (from 00000). The link
    settles the request with it but does not count it in the board's sequence: before, a
    00000 amid the board's counters was judged the board restarting (and the link set
    everything again), any other value a duplicate or a gap."""
    from fpgalink import Connection, ParameterRefused
    from fpgalink.events import BoardRestarted, RequestFailed
    from fpgalink.protocol import (
        DEFAULT_FRAMING,
        Alive,
        CountedMessage,
        NackReason,
        ParamNack,
        encode_frame,
        encode_message,
        lookup,
    )

    def frame(message: CountedMessage | ParamNack, counter: int) -> bytes:
        return encode_frame(encode_message(message, counter), DEFAULT_FRAMING)

    connection = Connection()
    connection.start(0.0)
    chatter = CountedMessage("ZZ", (), None)
    connection.receive_data(b"".join(frame(chatter, c) for c in range(500, 510)), 0.01)
    param = lookup("Kp_Wheel_Pid")
    request = connection.set_param(param, 1, 500.0, 0.02)
    connection.receive_data(frame(ParamNack(param.id, 1, NackReason.NOT_CONTROLLER), 0),
                            0.03)
    connection.receive_data(frame(chatter, 510) + encode_frame(Alive().content), 0.04)
    events = list(connection.events())
    (failed,) = [e for e in events if isinstance(e, RequestFailed)]
    assert failed.request_id == request and isinstance(failed.error, ParameterRefused)
    assert "refused by the router" in str(failed.error)
    assert not any(isinstance(e, BoardRestarted) for e in events)
    stats = connection.stats
    assert stats.duplicates == stats.lost == stats.restarts == 0
