"""Issue 41, the first hour of a new user: each item through the console scripts."""

from __future__ import annotations

import json
import os
import re
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support.cli import ROOT, completed
from tests.support.scripts import BIN, script, script_env, start_script, without
from tests.support.serving import Served, served


def _into_a_closed_pipe(*args: str) -> subprocess.CompletedProcess[str]:
    """``fpgalink-cli ARGS | head -0``: stdout is a pipe whose reader has already gone, so
    every write fails at once (``| head -1`` is the same, later)."""
    read, write = os.pipe()
    os.close(read)
    try:
        proc = start_script("fpgalink-cli", *args, stdout=write)
    finally:
        os.close(write)
    _, err = proc.communicate(timeout=60)
    return subprocess.CompletedProcess(proc.args, proc.returncode, "", err)


@pytest.mark.parametrize("args", [["budget"], ["budget", "--crc"], ["param", "list"],
                                  ["config"]])
def test_a_table_into_a_pipe_that_closed_ends_quietly_with_0(args: list[str]) -> None:
    """41.3: ``budget | head -1`` exited 1 silently (rich's console turned the broken pipe
    into exit 1)."""
    done = _into_a_closed_pipe(*args)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    assert "error" not in done.stderr


@pytest.mark.parametrize(("typed", "meant"), [
    ("KpWheelPidA", "Kp_Wheel_PidA"), ("kp-wheel-pid-b", "Kp_Wheel_PidB"),
    ("TsTimerPeriode", "TsTimerPeriod"), ("ActiveControler", "ActiveController"),
])
def test_an_unknown_parameter_name_gets_a_suggestion(typed: str, meant: str) -> None:
    """41.11: ``param set KpWheelPidA 5`` listed the bare names without the A/B suffix."""
    done = script("fpgalink-cli", "param", "set", typed, "5")
    assert done.returncode == 2
    assert f"did you mean {meant}?" in done.stderr, done.stderr
    assert "Kp_Wheel_PidA/B" in done.stderr  # the known names say where a suffix goes
    assert len(done.stderr.strip().splitlines()) <= 2  # the emulator's note, then one line


def test_a_name_like_none_gets_no_guess() -> None:
    done = script("fpgalink-cli", "param", "get", "xyz")
    assert done.returncode == 2
    assert "did you mean" not in done.stderr
    assert "unknown parameter 'xyz'" in done.stderr


TWO_BOARDS = ("--port", "L=emu://", "--port", "R=emu://?seed=2")


def test_param_list_with_two_boards_shows_a_column_per_board() -> None:
    """41.10: ``param list`` with two boards refused ("pick one with --board NAME")."""
    done = script("fpgalink-cli", "param", "list", *TWO_BOARDS)
    assert done.returncode == 0, done.stderr
    header = next(line for line in done.stdout.splitlines() if " name " in line)
    assert header.split("┃")[-3:-1] == ["     L ", "     R "] or \
        [c.strip() for c in header.split("┃")[-3:-1]] == ["L", "R"]
    row = next(line for line in done.stdout.splitlines() if "Kp_Wheel_PidB" in line)
    assert [c.strip() for c in row.split("│")[-3:-1]] == ["520.0", "520.0"]


def test_param_list_with_two_boards_on_a_narrow_terminal_is_a_table_each() -> None:
    done = script("fpgalink-cli", "param", "list", *TWO_BOARDS,
                  env=script_env(COLUMNS="40"))
    assert done.returncode == 0, done.stderr
    assert "Parameters on L (emu://)" in done.stdout
    assert "Parameters on R (emu://?seed=2)" in done.stdout


def test_param_list_with_two_boards_in_json_names_each_rows_board() -> None:
    done = script("fpgalink-cli", "param", "list", *TWO_BOARDS, "--format", "json")
    assert done.returncode == 0, done.stderr
    rows = json.loads(done.stdout)
    assert {r["board_name"] for r in rows} == {"L", "R"}
    assert len(rows) == 2 * len([r for r in rows if r["board_name"] == "L"])
    kp = [r for r in rows if r["name"] == "Kp_Wheel_Pid"]
    assert [(r["board_name"], r["A"], r["B"]) for r in kp] == [("L", 520.0, 520.0),
                                                               ("R", 520.0, 520.0)]


def test_param_list_with_board_picks_one() -> None:
    done = script("fpgalink-cli", "param", "list", *TWO_BOARDS, "--board", "R",
                  "--format", "json")
    assert done.returncode == 0, done.stderr
    assert "board_name" not in json.loads(done.stdout)[0]


def _driving(*args: str) -> subprocess.CompletedProcess[str]:
    """A robot command through the console script."""
    return script("fpgalink-cli", *args, timeout=120)


@pytest.fixture
def served_robot(tmp_path: Path) -> Iterator[Served]:
    """``fpgaemu serve --robot`` on two ptys behind links: the ports and the truth URL."""
    with served("--robot", "--body", "kinematic", "--pty", "--link", f"L={tmp_path / 'L'}",
                "--link", f"R={tmp_path / 'R'}", command=(str(BIN / "fpgaemu"),),
                env=script_env()) as server:
        assert server.truth is not None
        yield server


def test_truth_beside_a_served_robot_that_moved_before_is_from_the_start_pose(
        served_robot: Served) -> None:
    """41.2: against a served robot whose body had already moved, truth was compared in
    another frame ("odometry off by 134.0 cm"). (Over ptys a loaded machine may stop a
    command for real, measured: tests/support/cli.py's ``completed``.)"""
    server = served_robot
    assert server.truth is not None
    moved = _driving("drive", "--v", "0.3", "--omega", "30", "--for", "1.5", *server.ports)
    completed(moved, server)  # moved before, or stopped by load after moving some way
    done = _driving("goto", "0.4", "0", *server.ports, "--truth", server.truth, "--format",
                    "json")
    if not completed(done, server):
        return
    summary = json.loads(done.stdout)
    assert summary["truth"] is not None
    # The kinematic body moves as odometry counts: the same pose, within a centimetre.
    assert summary["truth"]["odometry_error_m"] < 0.01, summary
    assert abs(summary["truth"]["x_m"] - summary["odometry"]["x_m"]) < 0.01
    assert abs(summary["truth"]["theta_deg"]) < 1.0


def test_a_fault_stop_prints_the_final_pose_and_says_the_fault_once() -> None:
    """41.13: a fault stop printed no final pose (Ctrl-C did), and its message stuttered:
    "a board restarted (board L): restarted: reconfiguring (restarted: …)"."""
    fault = "fault=L:restart=1"
    done = _driving("drive", "--v", "0.2", "--for", "4", "--port", f"L=emu://robot/L?{fault}",
                    "--port", f"R=emu://robot/R?{fault}")
    assert done.returncode == 7, done.stderr
    assert done.stdout.startswith("odometry: x "), done.stdout
    assert "truth:" in done.stdout
    error = next(line for line in done.stderr.splitlines() if "error:" in line)
    assert error.count("restarted") <= 1, error
    assert "reconfiguring (restarted" not in done.stderr


#: What README's "Try it" and docs/cli.md's examples leave in the working directory.
TRY_IT_OUTPUTS = ("step.png", "run.mcap", "run.png", "drive.png", "path.png", "out/",
                  "seed36/", "bag1/", "bag2/")


def test_what_try_it_writes_is_ignored_by_git() -> None:
    """41.14: .gitignore had step.png but not what "Try it" writes."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    for name in ("run.mcap", "run.png"):
        assert name in readme  # still what the README's session writes
    done = subprocess.run(["git", "check-ignore", "--no-index", *TRY_IT_OUTPUTS], cwd=ROOT,
                          capture_output=True, text=True, check=False)
    assert sorted(done.stdout.split()) == sorted(TRY_IT_OUTPUTS), done.stderr


def test_the_suites_ros_logs_go_to_a_directory_of_its_own() -> None:
    """41.14: the suite left ROS logs in a fixed /tmp/fpgalink-ros."""
    logs = os.environ["ROS_LOG_DIR"]
    assert "fpgalink-tests-ros-logs-" in logs and Path(logs).is_dir()
    bench = (ROOT / "benchmarks" / "ros2.py").read_text(encoding="utf-8")
    assert '"fpgalink-ros"' not in bench


def test_a_robot_command_without_mujoco_says_the_body_once_in_its_own_line(
        tmp_path: Path) -> None:
    """41.7: every robot command printed an unprefixed MuJoCo-missing line besides its own."""
    done = script("fpgalink-cli", "drive", "--v", "0.1", "--for", "0.3",
                  env=without(tmp_path, "mujoco"), timeout=60)
    assert done.returncode in (0, 7), done.stderr
    lines = [line for line in done.stderr.splitlines() if "MuJoCo" in line]
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("fpgalink-cli: no --port given: using the built-in emulated "
                               "robot"), lines
    assert "the kinematic body" in lines[0] and "fpgalink[physics]" in lines[0]


def test_serve_robot_without_mujoco_says_it_once(tmp_path: Path) -> None:
    """41.7: ``fpgaemu serve --robot`` printed the notice twice, in two wordings."""
    with served("--robot", "--pty", command=(str(BIN / "fpgaemu"),),
                env=without(tmp_path, "mujoco")) as server:
        assert server.truth is not None and set(server.ready) == {"L", "R"}
    err = server.log_text()
    lines = [line for line in err.splitlines() if "MuJoCo" in line or "kinematic" in line]
    assert len(lines) == 1, err
    assert lines[0].startswith("fpgaemu: ")


WIRE_LINE = re.compile(r"^fpgalink-cli: (\w+) < ([A-Z]{1,2})\b.*\[([0-9a-f]{2}( [0-9a-f]{2})*)\]$")


def _wire_lines(stderr: str) -> list[re.Match[str]]:
    return [m for line in stderr.splitlines() if (m := WIRE_LINE.match(line))]


@pytest.mark.parametrize("args", [
    ["param", "get", "TsTimerPeriod"], ["param", "list"],
    ["monitor", "--duration", "0.3", "--format", "csv"],
    ["step", "--channel", "A", "--to", "10", "--pre", "0.1", "--hold", "0.2"],
    ["drive", "--v", "0.1", "--for", "0.3"], ["goto", "0.05", "0"],
])
def test_v_shows_each_message_a_board_sends_for_every_command(args: list[str]) -> None:
    """41.6: -v did nothing for most commands although every help says so."""
    quiet = _driving(*args)
    assert quiet.returncode == 0, quiet.stderr
    assert not _wire_lines(quiet.stderr)
    done = _driving("-v", *args)
    assert done.returncode == 0, done.stderr
    lines = _wire_lines(done.stderr)
    assert any(m.group(2) == "PA" for m in lines), done.stderr[-500:]
    assert not any(m.group(2) == "TM" for m in lines)  # telemetry only at -vv
    for m in lines:  # the bytes are the message's content: its ID first
        assert bytes.fromhex(m.group(3)).startswith(m.group(2).encode())


def test_vv_adds_the_telemetry() -> None:
    done = script("fpgalink-cli", "-vv", "monitor", "--duration", "0.3", "--format", "csv")
    assert done.returncode == 0, done.stderr
    assert sum(m.group(2) == "TM" for m in _wire_lines(done.stderr)) > 100
