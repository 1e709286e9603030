"""Helpers for the CLI tests: a scripted board in a thread and a runner for the CLI as a
subprocess (the emulator served on a pty comes from :mod:`tests.support.serving`).

``board`` (tests/fpgalink/cli/conftest.py) is parametrized over transports: ``fake`` (the
scripted board of :mod:`tests.support.fakeboard` on loopback TCP), ``emu`` (``emu://``, the
emulator in the CLI's own process) and ``pty`` (``fpgaemu serve --pty`` in a subprocess).
"""

from __future__ import annotations

import asyncio
import atexit
import dataclasses
import os
import shutil
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tests.support.fakeboard import FakeBoard, ScriptedBoard
from tests.support.serving import Served

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
    served: Served | None = None  #: the ``fpgaemu serve`` behind it (``pty``)
    cleanup: list[Callable[[], None]] = field(default_factory=list)


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


#: A serve that says it fell behind real time by more than this was behind by at least that
#: much, and possibly by far more: past one catch-up slice (fpgaemu.serve.CATCH_UP_SLICE_S,
#: 10 ms) it catches up slice by slice, and the served robot's lag is not observed again
#: while it does (its ``next_wake`` sets no deadline to measure against then). So a
#: reported worst of 17.8 ms came with a 50 ms gap in a board's telemetry (seen under load):
#: the report is a lower bound once past a slice.
LAG_EXPLAINS_S = 0.010
#: A serve that read nothing from the host for this long while its board was enabled got the
#: host's heartbeat (an ``RE`` every 100 ms) late: twice its interval, as the host says of
#: its own lateness (``host silent``). Seen under load with the host's own ``RE`` under 200 ms
#: apart and serve keeping up: the time went between them (the host's write after its
#: clock was read, the system's pty).
SILENCE_EXPLAINS_S = 0.200
#: What a command stopped by a fault says: exit 7 (``the robot was stopped: …``, ``the step
#: was stopped: …``, ``…: stopped: …``) or exit 4 (a board not answering).
_STOPPED = (7, 4)


def stopped_by_load(done: subprocess.CompletedProcess[str], *serves: Served) -> str | None:
    """Why ``done`` (a command that drove a served board for a while) was stopped by this
    machine's load, as measured, or ``None`` when it was not (it completed, or failed for
    another reason: the test's own assertion then says what went wrong).

    A loaded machine stops such a command for real: its host or the emulator not scheduled
    in time is, to the host, a board whose telemetry stopped or whose watchdog lapsed, and
    it stops as it must. Taken for that only when measured: the command says its own
    process was not scheduled (``host silent N ms``: its heartbeat overdue on its own
    clock), or a serve it talked to says it fell behind real time by more than
    :data:`LAG_EXPLAINS_S`, or that its board's watchdog lapsed after it read nothing from
    the host for :data:`SILENCE_EXPLAINS_S`. An in-process board (``emu://``) keeps its
    link on the board's own time, so a command on one is never stopped so: pass no serve
    for it."""
    if done.returncode not in _STOPPED:
        return None
    if "host silent" in done.stderr:
        return "its host was not scheduled: " + done.stderr.strip().splitlines()[-1]
    measured = [(server.describe(), server.report(), server) for server in serves]
    lags = [(served.worst_lag_s(report), where) for where, report, served in measured]
    if lags and (worst := max(lags))[0] > LAG_EXPLAINS_S:
        return f"{worst[1]} fell behind real time by {worst[0] * 1000:.0f} ms"
    silences = [(served.host_silence_s(report), where) for where, report, served in measured]
    if silences and (longest := max(silences))[0] >= SILENCE_EXPLAINS_S:
        return (f"{longest[1]}: its board's watchdog lapsed after it read nothing from the "
                f"host for {longest[0] * 1000:.0f} ms")
    return None


def completed(done: subprocess.CompletedProcess[str], *serves: Served) -> bool:
    """True when ``done`` exited 0; False when this machine's load stopped it, as measured
    (:func:`stopped_by_load`: said with its reason on stderr, so a run that tested less is
    seen); an ``AssertionError`` with its output otherwise."""
    if done.returncode == 0:
        return True
    why = stopped_by_load(done, *serves)
    assert why is not None, f"exit {done.returncode}:\n{done.stdout}\n{done.stderr}"
    print(f"stopped by this machine's load ({why}): {done.stderr.strip()}", file=sys.stderr)
    return False


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
