"""``budget``: the static calculator (needs fpgalink.budget, being written alongside)."""

from __future__ import annotations

import pytest
from cli_helpers import run_cli

pytestmark = pytest.mark.timeout(30)


def test_seed_case_does_not_fit_and_tm_alone_does() -> None:
    pytest.importorskip("fpgalink.budget", reason="fpgalink.budget not written yet")
    done = run_cli("budget", "--period-ms", "1", "--message", "BIG:200:1:down", "--check")
    assert done.returncode == 1, done.stderr
    assert "board→host" in done.stdout and "DOES NOT FIT" in done.stdout
    ok = run_cli("budget", "--period-ms", "1", "--check")
    assert ok.returncode == 0, ok.stderr
    assert "100.0 wire bytes" in ok.stdout


def test_bad_message_spec_exits_2() -> None:
    done = run_cli("budget", "--message", "RV:eight:1")
    assert done.returncode == 2
    assert "RV:eight:1" in done.stderr
