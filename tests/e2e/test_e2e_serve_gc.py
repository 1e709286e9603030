"""``fpgaemu serve`` keeps what it made at start-up out of the garbage collector's full
passes: a full collection walked every object of the process (about 50,000: the modules,
numpy's, the boards), 20-50 ms on a loaded machine with the event loop stopped, and a host
took the gap in telemetry for a board whose telemetry had stopped (the robot's real-life
tests failed so, 7 runs in 8, once the process held a few more classes).

What is asserted is what the collector would walk, read in the serving process by a probe
(SIGUSR2) installed before serve's own ``main`` runs: no wall-clock bound."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from typing import IO

import pytest

from tests.support.cli import ROOT, cli_env

pytestmark = pytest.mark.timeout(60)

PROBE = """
import gc, signal, sys
def probe(signum, frame):
    print(f"gen2 {len(gc.get_objects(2))} frozen {gc.get_freeze_count()}", file=sys.stderr,
          flush=True)
signal.signal(signal.SIGUSR2, probe)
sys.argv = ["fpgaemu", "serve", "--robot", "--pty", "--surface", "ideal", "--boards", "2"]
from fpgaemu.__main__ import main
main()
"""


def _line(stream: IO[str] | None, prefix: str) -> str:
    """The first line starting with ``prefix`` (blocking: serve prints it, or ends and the
    stream with it; the test's timeout bounds the wait)."""
    assert stream is not None
    for line in stream:
        if line.startswith(prefix):
            return line
    raise AssertionError(f"the stream ended before a line starting {prefix!r}")


def test_serve_keeps_its_start_up_heap_out_of_the_collectors_full_passes() -> None:
    proc = subprocess.Popen([sys.executable, "-c", PROBE], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT, env=cli_env())
    try:
        _line(proc.stdout, "ready truth")  # serving: every board is ready
        os.kill(proc.pid, signal.SIGUSR2)
        words = _line(proc.stderr, "gen2 ").split()
        walked, frozen = int(words[1]), int(words[3])
        assert frozen > 10_000, words  # the start-up heap, frozen
        assert walked < frozen // 10, words  # what a full pass walks while serving
    finally:
        proc.terminate()
        proc.wait(timeout=20)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()
