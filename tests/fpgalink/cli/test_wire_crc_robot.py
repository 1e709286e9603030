"""The robot's commands in the boards' wire-CRC mode: ``--wire-crc`` (and the config file's
``wire_crc``) reach the robot's links, and a robot whose boards send CRC-16 frames to a host
without it is told how to connect (issue 37.7 on the robot's path: ``--wire-crc`` was not
passed to the robot's links, so ``drive`` could not reach such boards at all)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support.cli import run_cli
from tests.support.serving import served

#: A served robot whose boards send CRC-16 frames (streaming, as a host left them).
SERVE = ("--robot", "--pty", "--surface", "ideal", "--body", "kinematic", "--set", "WireCrc=1",
         "--set", "GetDataPeriodical=1")


@pytest.fixture(scope="module")
def crc_robot() -> Iterator[list[str]]:
    """``--port`` options for a served robot whose boards send CRC-16 frames."""
    with served(*SERVE, shared=True) as server:
        yield server.ports


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
