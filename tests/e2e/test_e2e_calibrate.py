"""calibrate end to end on the MuJoCo body: ``fpgaemu serve --robot --pty --body mujoco``
(gravel, marble) driven by ``fpgalink-cli calibrate`` over its ptys against the served truth
port, the result saved into a robot file; then a fresh robot, the same 10 s turn in place
with the calibrated file: odometry's heading within 1 % of the angle turned (issue 40; with
the shipped robot file 3 % on gravel, 4 % on marble, 7 % with gravel's χ on marble). The
measured-angle path: the same recording calibrated from the angle the truth says, typed as
a user would, gives the same χ.

Each turn is measured from rest to rest, odometry and truth alike; the truth is the body's
own pose in emulated time, so the figures do not depend on this machine's load."""

from __future__ import annotations

import asyncio
import itertools
import json
from pathlib import Path
from typing import Any

import pytest

from fpgaemu import physics
from fpgalink.protocol.robot import load_robot
from tests.support.cli import run_cli, stalled
from tests.support.served import PATIENCE, Serve, serve

pytestmark = [pytest.mark.timeout(300),
              pytest.mark.skipif(not physics.available(),
                                 reason=physics.why_unavailable() or "")]

#: 20 deg/s until odometry says 200°: the issue's 10 s turn in place
TURN = ["--turn", "200", "--omega", "20"]


async def truth_url(server: Serve) -> str:
    assert server.proc.stdout is not None
    line = (await asyncio.wait_for(server.proc.stdout.readline(), PATIENCE)).decode().split()
    assert line[:2] == ["ready", "truth"], line
    return line[2]


async def calibrate_on_a_fresh_robot(surface: str, *options: str) -> dict[str, Any]:
    """A fresh served robot, calibrated; a run stopped by a stall of this loaded machine's
    own making (tests/support/cli.py's ``stalled``) is made again on another fresh one."""
    for _ in range(4):
        for option, value in itertools.pairwise(options):
            if option == "--record":
                Path(value).unlink(missing_ok=True)
        async with serve("--robot", "--pty", "--body", "mujoco", "--surface", surface,
                         boards=2) as server:
            url = await truth_url(server)
            done = await asyncio.to_thread(
                run_cli, "--port", f"L={server.ready['L']}", "--port",
                f"R={server.ready['R']}", "calibrate", "--surface", surface, "--truth", url,
                "--format", "json", *TURN, *options, timeout=120)
        if not stalled(done):
            break
    assert done.returncode == 0, done.stdout + done.stderr
    document: dict[str, Any] = json.loads(done.stdout)
    return document


@pytest.mark.parametrize("surface", ["gravel", "marble"])
async def test_after_calibrating_odometry_turns_within_a_percent(surface: str,
                                                                 tmp_path: Path) -> None:
    robot_file = tmp_path / "robot.toml"
    record = tmp_path / "turn.mcap"
    first = await calibrate_on_a_fresh_robot(surface, "--save", str(robot_file),
                                             "--record", str(record))
    (chi,) = first["results"]
    assert chi["name"] == "chi" and abs(chi["error_before_percent"]) > 2.0  # not vacuous
    assert load_robot(str(robot_file)).surfaces[surface] == pytest.approx(chi["after"],
                                                                          rel=1e-6)
    # the same turn on a fresh robot, odometry with the calibrated χ
    again = await calibrate_on_a_fresh_robot(surface, "--robot", str(robot_file))
    (check,) = again["results"]
    assert check["before"] == pytest.approx(chi["after"], rel=1e-6)
    assert abs(check["error_before_percent"]) <= 1.0, check
    assert check["reference_deg"] == pytest.approx(200, abs=20)

    # through a measured angle: the recording, and the angle the truth turned, typed in
    truth = await asyncio.to_thread(run_cli, "calibrate", "--from", str(record), "--format",
                                    "json")
    assert truth.returncode == 0, truth.stderr
    (from_truth,) = json.loads(truth.stdout)["results"]
    assert from_truth["after"] == pytest.approx(chi["after"], rel=1e-9)
    angle = f"{from_truth['reference_deg']:.6f}"
    given = await asyncio.to_thread(run_cli, "calibrate", "--from", str(record),
                                    "--measured-angle", angle, "--format", "json")
    typed = await asyncio.to_thread(run_cli, "calibrate", "--from", str(record),
                                    "--reference", "measured", "--format", "json",
                                    input=angle + "\n")
    for done in (given, typed):
        assert done.returncode == 0, done.stderr
        (measured,) = json.loads(done.stdout)["results"]
        assert measured["after"] == pytest.approx(chi["after"], rel=1e-6)
    assert "the angle the robot really turned" in typed.stderr


def test_a_measured_reference_without_a_value_or_terminal_is_refused() -> None:
    done = run_cli("calibrate", "--reference", "measured", "--port", "L=emu://robot/L",
                   "--port", "R=emu://robot/R")
    assert done.returncode == 2 and "nothing was driven" in done.stderr, done.stderr
