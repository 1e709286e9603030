"""Helpers for the CLI tests: a scripted board in a thread, the emulator served on a pty,
and a runner for the CLI as a subprocess.

``board`` (tests/fpgalink/cli/conftest.py) is parametrized over transports: ``fake`` (the
scripted board of :mod:`tests.support.fakeboard` on loopback TCP), ``emu`` (``emu://``, the
emulator in the CLI's own process) and ``pty`` (``fpgaemu serve --pty`` in a subprocess).
"""

from __future__ import annotations

import asyncio
import atexit
import contextlib
import dataclasses
import itertools
import os
import select
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tests.support.fakeboard import FakeBoard, ScriptedBoard

ROOT = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "fpgalink"]
#: Generous per-call bound: a hung CLI fails its test instead of the whole run.
CALL_TIMEOUT = 20.0


_SCRIPT_OPTIONS = {f.name for f in dataclasses.fields(ScriptedBoard)}


class BoardThread:
    """A FakeBoard serving from its own event loop in a thread, so a test can run the CLI
    as a blocking subprocess while the board answers. Options are the scripted board's
    (``nack=3``, ``mute=True``, ``echo=…``) or the server's (``silent``, ``tm_period``)."""

    def __init__(self, **options: Any) -> None:
        options.setdefault("values", {(2, 0): 0})  # telemetry off, as a board powers up
        script = ScriptedBoard(**{k: v for k, v in options.items() if k in _SCRIPT_OPTIONS})
        self.board = FakeBoard(script, **{k: v for k, v in options.items()
                                          if k not in _SCRIPT_OPTIONS})
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self._thread.start()
        self.url = self.call(self.board.start())

    def call(self, coro: Any) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout=5)

    def close(self) -> None:
        self.call(self.board.stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(timeout=5)
        self.loop.close()


@dataclass
class Board:
    """What a test needs to know about the board behind ``url``."""

    kind: str  #: fake, emu or pty
    url: str
    fake: FakeBoard | None = None  #: the scripted board, to inspect what it received
    has_dynamics: bool = False  #: a real plant behind it (the emulator)
    #: the board outlives one CLI command (emu:// boots a fresh board in each process)
    persistent: bool = True
    cleanup: list[Callable[[], None]] = field(default_factory=list)


@contextlib.contextmanager
def served_pty(*options: str) -> Iterator[str]:
    """``fpgaemu serve --pty OPTIONS`` while the block runs: its pty's path; stopped (and
    reaped) afterwards."""
    proc, path = serve_pty(*options)
    try:
        yield path
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def serve_pty(*options: str) -> tuple[subprocess.Popen[str], str]:
    """``fpgaemu serve --pty OPTIONS`` and its pty's path, once ready."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "fpgaemu", "serve", "--pty", *options],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )
    assert proc.stdout is not None
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 0.1)
        if ready:
            line = proc.stdout.readline()
            if line.startswith("ready "):
                return proc, line.split()[2]
            if not line and proc.poll() is not None:
                break
    proc.kill()
    raise RuntimeError(f"fpgaemu serve --pty did not become ready: {proc.stderr.read()!r}"
                       if proc.stderr else "fpgaemu serve --pty did not become ready")


_EMPTY_CONFIG_HOME = tempfile.mkdtemp(prefix="fpgalink-tests-config-")
atexit.register(shutil.rmtree, _EMPTY_CONFIG_HOME, True)


def cli_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("FPGALINK_")}
    # The user's own config file must not steer the tests (and matplotlib may write its
    # cache under XDG_CONFIG_HOME, so it must be a real, private directory).
    env.update(COLUMNS="200", NO_COLOR="1", PYTHONUNBUFFERED="1",
               XDG_CONFIG_HOME=_EMPTY_CONFIG_HOME)
    env.update(extra)
    return env


def run_cli(*args: str, env: dict[str, str] | None = None, input: str | None = None,
            timeout: float = CALL_TIMEOUT, cwd: Path | None = None
            ) -> subprocess.CompletedProcess[str]:
    """The CLI as a subprocess. From another ``cwd`` it still imports this checkout's
    packages (PYTHONPATH), as an installed CLI would."""
    env = env or cli_env()
    if cwd is not None:
        env = {**env, "PYTHONPATH": os.pathsep.join(
            [str(ROOT / "src"), str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
    return subprocess.run([*CLI, *args], capture_output=True, text=True, cwd=cwd or ROOT,
                          env=env, input=input, timeout=timeout)


#: What a loaded machine's own stall looks like to a robot command (exit 7): the host or
#: the in-process emulated robot was not scheduled for longer than a fault's threshold (a
#: silence long enough is also taken for a restart).
STALL_FAULTS = ("telemetry stopped", "watchdog", "disabled itself", "not answering",
                "after a silence", "not renewed")
#: Options whose file or directory a run writes, removed before it is run again.
_OUTPUTS = ("--record", "--rosbag2", "--plot", "-o", "--output")


def stalled(done: subprocess.CompletedProcess[str]) -> bool:
    """Exit 7 for a fault of the loaded machine's own making (see STALL_FAULTS)."""
    return done.returncode == 7 and any(f in done.stderr for f in STALL_FAULTS)


def run_driving(*args: str, tries: int = 3, **options: Any
                ) -> subprocess.CompletedProcess[str]:
    """``run_cli`` for a test whose command drives the robot (or steps a wheel) for
    something else (a recording, a plot, a parser, an exit code): a run stopped by a fault
    of the loaded machine's own making is run again, its outputs removed first, as
    tests/support/driving.py drives on through them in the library's tests. Any other
    outcome is returned as is."""
    done = run_cli(*args, **options)
    for _ in range(tries - 1):
        if not stalled(done):
            break
        for option, value in itertools.pairwise(args):
            if option in _OUTPUTS:
                path = Path(value)
                if path.is_dir():
                    shutil.rmtree(path)
                elif path.exists():
                    path.unlink()
        done = run_cli(*args, **options)
    return done


def start_cli(*args: str, env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    return subprocess.Popen([*CLI, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=ROOT, env=env or cli_env())


#: A private tmpfs needs root (for the mount namespace) and util-linux's unshare.
CAN_MOUNT = (sys.platform == "linux" and os.geteuid() == 0
             and shutil.which("unshare") is not None)


def cli_on_small_disk(tmp_path: Path, size: str, output: str, *args: str,
                      timeout: float = 120) -> tuple[subprocess.CompletedProcess[str], Path]:
    """``fpgalink-cli ARGS`` writing ``output`` (a file or directory name, ``{out}`` in
    ``args``) on a tmpfs of ``size`` in a private mount namespace, so the disk fills; what it
    wrote is copied out before the namespace (and the tmpfs) goes away. Skips the test when
    no tmpfs can be mounted here."""
    import pytest

    small = tmp_path / "small"
    small.mkdir()
    command = " ".join(CLI + [a.replace("{out}", str(small / output)) for a in args])
    script = (f"mount -t tmpfs -o size={size} tmpfs {small} || exit 97\n{command}\n"
              f"rc=$?\ncp -r {small / output} {tmp_path / output}\nexit $rc\n")
    done = subprocess.run(["unshare", "--mount", "sh", "-c", script], capture_output=True,
                          text=True, cwd=ROOT, env=cli_env(), timeout=timeout)
    if done.returncode == 97:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    return done, tmp_path / output
