"""The one way the tests, the ROS peer and the benchmarks start ``fpgaemu serve``: a board (or
several, or the robot) on ptys or TCP, with any of serve's options (``--link``, ``--fault``,
``--set`` …), waited for until it printed its ``ready`` lines, and owned until it is
stopped: its process (SIGTERM, then SIGKILL), its log (stderr, in a file, read on failure:
tests/conftest.py adds the logs of a failed test's serves to its report) and its clean-up
(a serve a test left running is stopped after it).

    with served("--robot", "--pty", "--surface", "ideal") as srv:
        srv.ready       # {"L": "/dev/pts/4", "R": "/dev/pts/5"}
        srv.truth       # "socket://127.0.0.1:40411"
    async with serve("--pty", "--fault", "restart=2") as srv: ...

Nothing here needs pytest or an event loop (the ROS peer runs it as a plain program); the
async form waits in a thread. serve's stdout carries only its ready lines, printed in one
write (so read whole from the pipe); everything else it says goes to the log.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "READY_TIMEOUT_S",
    "STOP_TIMEOUT_S",
    "ServeExited",
    "Served",
    "peek_since",
    "serve",
    "served",
    "start_serve",
    "started",
    "take_since",
]

#: Starting an interpreter and the emulator takes about half a second on a quiet machine;
#: on a loaded one (three test workers, busy loops, six processes starting at once) it has
#: taken over ten. The wait ends as soon as serve is ready, so a generous bound costs
#: nothing when all is well.
READY_TIMEOUT_S = 60.0
#: SIGTERM, then this long before SIGKILL (serve prints its accounting on the way out).
STOP_TIMEOUT_S = 10.0
#: How serve is run unless a test names another command (a console script, say).
PYTHON_M_FPGAEMU = (sys.executable, "-m", "fpgaemu")

#: The first words of each board's line in serve's report (on exit and on SIGUSR1).
_REPORT = ": host → board "
_LAG = re.compile(r"^(\S+): fell behind real time (\d+) times, worst ([\d.,]+) ms", re.M)
_SILENT = re.compile(r"^(\S+): watchdog lapsed (\d+) times; the host wrote nothing for up to "
                     r"([\d.,]+) ms", re.M)

#: Every serve started in this process, in order (tests/conftest.py reads the logs of those
#: a failed test started, and stops any a test left running).
_STARTED: list[Served] = []


class ServeExited(AssertionError):
    """``fpgaemu serve`` ended (or never got ready) before it printed its ready lines; the
    message carries its log."""


@dataclass
class Served:
    """A running ``fpgaemu serve`` and what it printed."""

    args: tuple[str, ...]
    proc: subprocess.Popen[bytes]
    log: Path  #: serve's stderr: what it says while serving, and its accounting at exit
    #: each board's address as serve printed it first (its pty, the ``--link`` path, or a
    #: ``socket://`` URL): what a host opens
    ready: dict[str, str] = field(default_factory=dict)
    #: with ``--link NAME=PATH``: each board's pty behind the link
    ptys: dict[str, str] = field(default_factory=dict)
    truth: str | None = None  #: the robot's truth endpoint (``--robot``)
    foxglove: str | None = None  #: the live view's address (``--foxglove``)
    #: every ready line's words, in order (a TCP board listening on IPv4 and IPv6 has two)
    lines: list[list[str]] = field(default_factory=list)
    #: the directory made for the log (none given): removed by :meth:`discard`
    own_dir: Path | None = None

    @property
    def url(self) -> str:
        """The first board's address."""
        return next(iter(self.ready.values()))

    @property
    def ports(self) -> list[str]:
        """``--port NAME=ADDRESS`` for each board, as fpgalink-cli and the node take them."""
        return [f"--port={name}={where}" for name, where in self.ready.items()]

    @property
    def pid(self) -> int:
        return self.proc.pid

    @property
    def running(self) -> bool:
        return self.proc.poll() is None

    @property
    def exit_code(self) -> int | None:
        return self.proc.poll()

    def send_signal(self, sig: int) -> None:
        if self.running:
            self.proc.send_signal(sig)

    def wait(self, timeout: float = STOP_TIMEOUT_S) -> int:
        return self.proc.wait(timeout)

    def stop(self, sig: int = signal.SIGTERM, timeout: float = STOP_TIMEOUT_S) -> int:
        """``sig`` (SIGTERM: serve ends cleanly and prints its accounting), SIGKILL if it has
        not ended within ``timeout``; its exit code. Safe to call again."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout is not None and not self.proc.stdout.closed:
            self.proc.stdout.close()
        return self.proc.returncode

    def kill(self) -> int:
        return self.stop(signal.SIGKILL)

    async def stopped(self, sig: int = signal.SIGTERM, timeout: float = STOP_TIMEOUT_S
                      ) -> int:
        """:meth:`stop` from a coroutine: waited for in a thread, the loop running on."""
        return await asyncio.to_thread(self.stop, sig, timeout)

    async def exited(self, timeout: float = STOP_TIMEOUT_S) -> int:
        """Its exit code once it ends by itself (``TimeoutError`` after ``timeout``)."""
        try:
            return await asyncio.to_thread(self.proc.wait, timeout)
        except subprocess.TimeoutExpired:
            raise TimeoutError(f"{self.describe()} still running after {timeout:g} s"
                               ) from None

    def discard(self) -> None:
        """Stopped, and the log's own directory gone (the log of a serve given a
        ``log_dir`` is kept: it is the caller's)."""
        self.stop()
        if self.own_dir is not None:
            shutil.rmtree(self.own_dir, ignore_errors=True)
            self.own_dir = None

    def log_text(self) -> str:
        try:
            return self.log.read_text(encoding="utf-8", errors="replace")
        except OSError as exc:
            return f"(serve's log {self.log} unreadable: {exc})"

    def report(self) -> str:
        """Serve's log with its report as of now (asked for with SIGUSR1 while it runs;
        printed when it stops)."""
        if self.running:
            reports = self.log_text().count(_REPORT)
            self.proc.send_signal(signal.SIGUSR1)
            deadline = time.monotonic() + STOP_TIMEOUT_S
            while self.running and self.log_text().count(_REPORT) <= reports:
                if time.monotonic() > deadline:
                    raise AssertionError(f"{self.describe()}: no report on SIGUSR1")
                time.sleep(0.01)
        return self.log_text()

    def worst_lag_s(self, report: str | None = None) -> float:
        """How far behind real time serve's boards fell at worst so far (0 when they never
        did), as serve itself reports it (:meth:`report`): on a loaded machine a starved
        emulator hands its boards' telemetry out late, and puts what the host wrote on their
        lines late, and a host rightly takes a long enough gap for a board that stopped."""
        text = self.report() if report is None else report
        worst = [float(ms.replace(",", "")) / 1000 for *_, ms in _LAG.findall(text)]
        return max(worst, default=0.0)

    def host_silence_s(self, report: str | None = None) -> float:
        """Of the boards whose watchdog lapsed, the longest serve read nothing from the host
        while one was enabled (0 when none lapsed): the host's heartbeat reaching serve late,
        its process or the system between them not scheduled in time."""
        text = self.report() if report is None else report
        silent = [float(ms.replace(",", "")) / 1000 for *_, ms in _SILENT.findall(text)]
        return max(silent, default=0.0)

    def describe(self) -> str:
        return f"fpgaemu serve {' '.join(self.args)}"


def start_serve(*args: str, log_dir: Path | None = None, env: dict[str, str] | None = None,
                command: Sequence[str] = PYTHON_M_FPGAEMU, cwd: Path | None = None,
                ready_timeout: float = READY_TIMEOUT_S, shared: bool = False,
                **popen: Any) -> Served:
    """Start ``fpgaemu serve ARGS`` and return once it printed its ready lines.
    ``log_dir``: where its log goes (a directory of its own otherwise); ``command``: how serve
    is run (the environment's console script, say); ``shared``: a module's or a session's
    fixture owns it, so it outlives the test that started it (neither stopped after that
    test nor its log in that test's report); ``popen``: more for the subprocess
    (``preexec_fn``, say). :class:`ServeExited` with its log if it ends first."""
    directory = log_dir if log_dir is not None else Path(
        tempfile.mkdtemp(prefix="fpgaemu-serve-"))
    directory.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix="serve-", suffix=".log", dir=directory)
    log = Path(name)
    with os.fdopen(fd, "wb") as err:
        proc = subprocess.Popen([*command, "serve", *args], stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=err, env=env, cwd=cwd,
                                **popen)
    server = Served(tuple(args), proc, log, own_dir=None if log_dir is not None else directory)
    if not shared:
        _STARTED.append(server)
    try:
        _read_ready(server, ready_timeout)
    except BaseException:
        server.stop()
        raise
    return server


def _read_ready(server: Served, timeout: float) -> None:
    """serve prints its ready lines in one write, at once: read until a whole line came."""
    assert server.proc.stdout is not None
    out = server.proc.stdout.fileno()
    got = b""
    deadline = time.monotonic() + timeout
    while not got.endswith(b"\n"):
        left = deadline - time.monotonic()
        if left <= 0:
            raise ServeExited(f"{server.describe()}: not ready after {timeout:g} s; its log:\n"
                              f"{server.log_text()}")
        if not select.select([out], [], [], min(left, 1.0))[0]:
            continue
        chunk = os.read(out, 65536)
        if not chunk:
            code = server.stop()
            raise ServeExited(f"{server.describe()} ended (exit {code}) before it was ready; "
                              f"its log:\n{server.log_text()}")
        got += chunk
    for line in got.decode().splitlines():
        words = line.split()  # "ready L /dev/pts/4", "ready L LINK -> /dev/pts/4"
        if not words:
            continue
        assert words[0] == "ready" and len(words) >= 3, f"{server.describe()}: {line!r}"
        server.lines.append(words)
        name, where = words[1], words[2]
        if name == "truth":
            server.truth = server.truth or where
        elif name == "foxglove":
            server.foxglove = where
        else:
            server.ready.setdefault(name, where)
            if len(words) >= 5 and words[3] == "->":
                server.ptys[name] = words[4]


@contextlib.contextmanager
def served(*args: str, **options: Any) -> Iterator[Served]:
    """``with served("--pty") as srv:``: stopped (and reaped) afterwards, whatever happened."""
    server = start_serve(*args, **options)
    try:
        yield server
    finally:
        server.stop()


@contextlib.asynccontextmanager
async def serve(*args: str, **options: Any) -> AsyncIterator[Served]:
    """``async with serve("--pty") as srv:``: as :func:`served`, waiting in a thread so the
    test's loop runs on meanwhile."""
    server = await asyncio.to_thread(start_serve, *args, **options)
    try:
        yield server
    finally:
        await asyncio.to_thread(server.stop)


def started() -> int:
    """How many serves this process has started: a mark for :func:`take_since`."""
    return len(_STARTED)


def peek_since(mark: int) -> list[Served]:
    """The serves started since ``mark`` (:func:`started`)."""
    return _STARTED[mark:]


def take_since(mark: int) -> list[Served]:
    """The serves started since ``mark`` (:func:`started`), no longer kept here."""
    taken = _STARTED[mark:]
    del _STARTED[mark:]
    return taken
