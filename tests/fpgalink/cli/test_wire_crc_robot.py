"""The robot's commands in the boards' wire-CRC mode: ``--wire-crc`` (and the config file's
``wire_crc``) reach the robot's links, and a robot whose boards send CRC-16 frames to a host
without it is told how to connect (issue 37.7 on the robot's path: ``--wire-crc`` was not
passed to the robot's links, so ``drive`` could not reach such boards at all)."""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support.cli import ROOT, run_cli

SERVE = (sys.executable, "-m", "fpgaemu", "serve", "--robot", "--pty", "--surface", "ideal",
         "--body", "kinematic", "--set", "WireCrc=1", "--set", "GetDataPeriodical=1")


@pytest.fixture(scope="module")
def crc_robot() -> Iterator[list[str]]:
    """A served robot whose boards send CRC-16 frames (streaming, as a host left them):
    ``--port`` options for it."""
    proc = subprocess.Popen(SERVE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, cwd=ROOT)
    try:
        ready = _ready(proc, 60.0)
        yield ["--port", f"L={ready['L']}", "--port", f"R={ready['R']}"]
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _ready(proc: subprocess.Popen[bytes], timeout: float) -> dict[str, str]:
    """serve's ``ready NAME PATH`` lines, up to its truth port's (read unbuffered: serve
    prints them in one write)."""
    assert proc.stdout is not None
    out = b""
    deadline = time.monotonic() + timeout
    while b"ready truth" not in out and time.monotonic() < deadline:
        if select.select([proc.stdout], [], [], 0.5)[0]:
            chunk = os.read(proc.stdout.fileno(), 4096)
            assert chunk, f"fpgaemu serve ended before it was ready: {out!r}"
            out += chunk
    lines = [line.split() for line in out.decode().splitlines()]
    ready = {words[1]: words[2] for words in lines if len(words) == 3 and words[0] == "ready"}
    assert "truth" in ready, f"fpgaemu serve not ready in {timeout:g} s: {out!r}"
    return ready


def test_a_robot_of_crc_boards_without_the_crc_says_how_to_connect(
        crc_robot: list[str]) -> None:
    done = run_cli("drive", "--for", "0.5", "--v", "0.05", *crc_robot)
    assert done.returncode == 4, done.stderr
    assert "the board sends CRC-16 frames; connect with the CRC on (--wire-crc" in done.stderr


@pytest.mark.parametrize("how", ["option", "config"])
def test_the_robot_connects_in_the_crc_mode_when_asked(
        crc_robot: list[str], how: str, tmp_path: Path) -> None:
    """The robot started, its boards answered in their mode: the drive's odometry line."""
    if how == "option":
        done = run_cli("--wire-crc", "drive", "--for", "0.5", "--v", "0.05", *crc_robot)
    else:
        config = tmp_path / "fpgalink.toml"
        config.write_text("wire_crc = true\n", encoding="utf-8")
        done = run_cli("--config", str(config), "drive", "--for", "0.5", "--v", "0.05",
                       *crc_robot)
    assert "CRC-16" not in done.stderr and "not answering" not in done.stderr, done.stderr
    # 0, or 7 when a loaded machine's stall stopped the drive after the robot had started.
    assert done.returncode in (0, 7), done.stderr
    assert "odometry: x " in done.stdout + done.stderr
