"""Fault specs where the emulator takes them (``fpgaemu serve --fault``, ``emu://…?fault=``):
every number bounded when the spec is parsed, one line naming the bound, nothing served;
and what the worst spec within the bounds can make a board allocate."""

from __future__ import annotations

import subprocess
import sys
import tracemalloc

import pytest

from fpgaemu import build_board
from fpgaemu.uart import LineFaults
from fpgalink.protocol.faults import MAX_FAULTS, MAX_NOISE_LEN
from tests.fpgalink.cli.test_errors import assert_one_line_error
from tests.support.cli import ROOT, cli_env, run_cli

pytestmark = pytest.mark.timeout(90)


def fpgaemu(*args: str) -> subprocess.CompletedProcess[str]:
    # Before the bounds, these specs were taken and serve served (until this timeout) with
    # a board that broke at its first burst.
    return subprocess.run([sys.executable, "-m", "fpgaemu", *args], capture_output=True,
                          text=True, timeout=30, cwd=ROOT, env=cli_env())


@pytest.mark.parametrize(("faults", "says"), [
    (["tx-noise=1:100000000000"], "LEN must be a whole number from 1 to 16"),
    (["rx-noise=1:100000000000"], "LEN must be a whole number from 1 to 16"),
    (["L:rx-noise=0.5:17"], "LEN must be a whole number from 1 to 16"),
    (["drop-frames=PS:99999999999"], "N must be a whole number from 0 to 1,000,000,000"),
    (["restart=1e300"], "T_S must be seconds from 0 to 31,536,000 (a year)"),
    (["tm-loss=1:1e300"], "DURATION_S must be seconds"),
    ([f"restart={t}" for t in range(MAX_FAULTS + 1)], f"at most {MAX_FAULTS}"),
], ids=["tx-noise", "rx-noise", "board-noise", "drop-frames", "restart", "tm-loss", "count"])
def test_serve_refuses_a_spec_out_of_bounds_in_one_line(faults: list[str], says: str) -> None:
    done = fpgaemu("serve", "--tcp", "127.0.0.1:0", "--boards", "2",
                   *[a for fault in faults for a in ("--fault", fault)])
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith("fpgaemu: error: ") and says in done.stderr, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
    assert "ready" not in done.stdout


@pytest.mark.parametrize("url", [
    "emu://?fault=tx-noise=1:100000000000",
    "emu://robot/L?fault=L:rx-noise=1:100000000000",
])
def test_an_emu_url_with_a_spec_out_of_bounds_is_one_line(url: str) -> None:
    done = run_cli("param", "get", "TsTimerPeriod", "--port", url)
    assert done.returncode == 2, done.stderr  # bad input: the URL written wrong (one table)
    assert_one_line_error(done.stderr, "LEN must be a whole number from 1 to 16")


def test_the_noise_burst_is_bounded_for_every_line_faults() -> None:
    LineFaults(noise_rate=1.0, noise_len=MAX_NOISE_LEN)
    with pytest.raises(ValueError, match=r"noise_len must be 1\.\.16"):
        LineFaults(noise_rate=1.0, noise_len=MAX_NOISE_LEN + 1)


def test_the_worst_noise_within_the_bounds_takes_little_memory() -> None:
    """The most a host can hand the RX line at once (serve's 4 KiB backlog) with noise
    before every byte at the longest burst: 69,632 wire bytes laid out bit by bit."""
    board = build_board(faults=[f"rx-noise=1:{MAX_NOISE_LEN}"])
    tracemalloc.start()
    try:
        board.host_write(bytes(4096), 0)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert board.uartread.stats.noise_bytes == 4096 * MAX_NOISE_LEN
    assert peak < 32e6, f"{peak / 1e6:.1f} MB"
