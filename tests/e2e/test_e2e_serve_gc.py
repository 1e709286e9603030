"""``fpgaemu serve`` keeps what it made at start-up out of the garbage collector's full
passes: a full collection walked every object of the process (about 50,000: the modules,
numpy's, the boards), 20-50 ms on a loaded machine with the event loop stopped, and a host
took the gap in telemetry for a board whose telemetry had stopped (the robot's real-life
tests failed so, 7 runs in 8, once the process held a few more classes).

What is asserted is what the collector would walk, read in the serving process by a probe
(SIGUSR2) installed before serve's own ``main`` runs: no wall-clock bound."""

from __future__ import annotations

import signal
import sys

import pytest

from tests.support.cli import ROOT, cli_env
from tests.support.serving import served
from tests.support.waiting import wait_until_sync

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


def test_serve_keeps_its_start_up_heap_out_of_the_collectors_full_passes() -> None:
    # serve's own command line is the probe's (its argv set there): the helper's is ignored.
    with served(command=(sys.executable, "-c", PROBE), env=cli_env(), cwd=ROOT) as server:
        assert server.truth is not None  # serving: every board is ready
        server.send_signal(signal.SIGUSR2)
        wait_until_sync(lambda: "gen2 " in server.log_text(), 30, "the probe's line")
        line = next(li for li in server.log_text().splitlines() if li.startswith("gen2 "))
        words = line.split()
        walked, frozen = int(words[1]), int(words[3])
        assert frozen > 10_000, words  # the start-up heap, frozen
        assert walked < frozen // 10, words  # what a full pass walks while serving
