"""Issue 41, the first hour of a new user: each item through the console scripts."""

from __future__ import annotations

import json
import os
import subprocess

import pytest

from tests.support.scripts import script, script_env, start_script


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
