"""One output contract (issue 26), through the console script: every command that prints
data takes ``--format table|json|csv``; JSON is one document with numbers as numbers and
the unit in the key, ``[]`` when there is nothing; tables fit 80 columns without cutting a
name; a full stdout is one line and exit 1; bare groups print their help; negative numbers
as written; an explicit --port wins over the file's board; SIGTERM disables as Ctrl-C."""

from __future__ import annotations

import csv
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from tests.fpgalink.cli.test_errors import assert_one_line_error
from tests.support.cli import CLI, ROOT, BoardThread, cli_env
from tests.support.serving import served
from tests.support.waiting import wait_until_sync

pytestmark = pytest.mark.timeout(120)

#: The console script the package installs (what a user types); ``python -m fpgalink``
#: when the tests run without an installed script.
_SCRIPT = Path(sys.executable).parent / "fpgalink-cli"
SCRIPT = [str(_SCRIPT)] if _SCRIPT.exists() else CLI


def cli(*args: str, env: dict[str, str] | None = None, timeout: float = 60,
        stdout: Any = subprocess.PIPE, cwd: Path | None = None
        ) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*SCRIPT, *args], stdout=stdout, stderr=subprocess.PIPE, text=True,
                          cwd=cwd or ROOT, env=env or cli_env(), timeout=timeout)


NUMBER_WITH_UNIT = re.compile(r"^[-+]?\d+(\.\d+)?(e[-+]?\d+)?\s*(s|ms|%|deg/s|B|m|A)$")


def numbers_only(value: Any, path: str = "") -> None:
    """No number in a JSON document is written as a string with a unit ("0.05 s")."""
    if isinstance(value, dict):
        for key, item in value.items():
            numbers_only(item, f"{path}.{key}")
    elif isinstance(value, list):
        for i, item in enumerate(value):
            numbers_only(item, f"{path}[{i}]")
    elif isinstance(value, str) and NUMBER_WITH_UNIT.match(value):
        raise AssertionError(f"{path}: {value!r} is a number written as a string")


# --- JSON: one document, numbers as numbers ---------------------------------------------------

def test_param_list_json_csv_and_table(fake_board: Callable[..., BoardThread]) -> None:
    fake = fake_board(values={(2, 0): 0, (1, 0): 4})
    done = cli("param", "list", "--format", "json", "--port", fake.url)
    assert done.returncode == 0, done.stderr
    rows = json.loads(done.stdout)  # one document, not JSON Lines
    assert isinstance(rows, list) and len(rows) >= 10
    period = next(r for r in rows if r["name"] == "TsTimerPeriod")
    assert period["board"] == 4 and period["A"] is None and isinstance(period["id"], int)
    # The range as numbers too, not only "1..1000" (an unbounded side null).
    assert (period["min"], period["max"], period["min_exclusive"]) == (1, 1000, False)
    ti = next(r for r in rows if r["name"] == "Ti_Wheel_Pid")
    assert (ti["min"], ti["max"], ti["min_exclusive"]) == (0, None, True)
    direction = next(r for r in rows if r["name"] == "IncSenzCountDirection")
    assert direction["allowed"] == [-1, 1] and period["allowed"] is None
    numbers_only(rows)
    done = cli("param", "list", "--format", "csv", "--port", fake.url)
    assert done.returncode == 0, done.stderr
    table = list(csv.DictReader(io.StringIO(done.stdout)))
    assert len(table) == len(rows) and {r["name"] for r in table} == {r["name"] for r in rows}
    assert next(r for r in table if r["name"] == "IncSenzCountDirection")["allowed"] == "-1 1"


def test_param_get_and_set_json(fake_board: Callable[..., BoardThread]) -> None:
    fake = fake_board(values={(2, 0): 0, (1, 0): 4})
    done = cli("param", "get", "TsTimerPeriod", "--format", "json", "--port", fake.url)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["value"] == 4
    done = cli("param", "set", "TsTimerPeriod", "5", "--format", "json", "--port", fake.url)
    assert done.returncode == 0, done.stderr
    document = json.loads(done.stdout)
    assert document["value"] == 5 and document["confirmed"] is True


def test_budget_json_is_numbers_with_units_in_the_keys() -> None:
    done = cli("budget", "--format", "json")
    assert done.returncode == 0, done.stderr
    document = json.loads(done.stdout)
    assert document["baud"] == 1_000_000 and isinstance(document["fits"], bool)
    assert all(isinstance(f["wire_bytes"], int) for f in document["flows"])
    assert isinstance(document["capacity_wire_bytes_per_period"], float)
    numbers_only(document)
    done = cli("budget", "--format", "csv")
    assert done.returncode == 0, done.stderr
    header = done.stdout.splitlines()[0].split(",")
    assert "wire_bytes" in header and "share" in header


def test_config_json_has_numbers_not_text_with_units() -> None:
    done = cli("config", "--format", "json")
    assert done.returncode == 0, done.stderr
    settings = json.loads(done.stdout)["settings"]
    assert settings["timeout_s"]["value"] == 0.05  # not "0.05 s"
    assert settings["baud"]["value"] == 1_000_000
    numbers_only(settings)


def test_ports_json_is_one_array_even_when_empty() -> None:
    # No serial port at all: `[]`, not nothing (the in-process run can hide the machine's).
    code = ("import sys, serial.tools.list_ports as lp; lp.comports = lambda *a, **k: []; "
            "from fpgalink.cli import main; sys.argv = ['fpgalink-cli'] + sys.argv[1:]; main()")
    done = subprocess.run([sys.executable, "-c", code, "ports", "--all", "--format", "json"],
                          capture_output=True, text=True, cwd=ROOT, env=cli_env(), timeout=60)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == []
    done = cli("ports", "--all", "--format", "json")  # this machine's, whatever they are
    assert done.returncode == 0, done.stderr
    assert isinstance(json.loads(done.stdout), list)


def test_step_json_has_the_figures_as_numbers() -> None:
    done = cli("step", "--channel", "A", "--to", "45", "--pre", "0.1",
                              "--hold", "0.6", "--format", "json", "--port", "emu://")
    assert done.returncode == 0, done.stderr
    document = json.loads(done.stdout)
    assert document["channel"] == "A" and document["to_dps"] == 45
    assert isinstance(document["rise_time_s"], float) and document["samples"] > 10
    assert isinstance(document["kp"], float) and isinstance(document["max_control_signal"], int)
    numbers_only(document)


def test_step_table_gives_a_unit_for_every_figure() -> None:
    done = cli("step", "--channel", "A", "--to", "45", "--pre", "0.1",
                              "--hold", "0.6", "--port", "emu://")
    assert done.returncode == 0, done.stderr
    rows = [li for li in done.stdout.splitlines() if li.startswith("│")]
    figures = [r for r in rows if "figure" not in r]
    assert len(figures) == 5
    for row in figures:
        assert any(unit in row for unit in (" s ", " %", "deg/s", "not reached")), row


def test_send_json_is_one_document(fake_board: Callable[..., BoardThread]) -> None:
    fake = fake_board()
    done = cli("send", "PG", "--hex", "0100", "--reply", "PA", "--format", "json",
               "--port", fake.url)
    assert done.returncode == 0, done.stderr
    document = json.loads(done.stdout)
    assert document["sent"]["id"] == "PG" and isinstance(document["sent"]["wire_bytes"], int)
    assert document["reply"]["id"] == "PA" and isinstance(document["reply"]["counter"], int)


# --- tables in 80 columns ---------------------------------------------------------------------

def test_param_list_fits_80_columns_without_cutting_a_name(
    fake_board: Callable[..., BoardThread]
) -> None:
    fake = fake_board()
    done = cli("param", "list", "--port", fake.url, env=cli_env(COLUMNS="80"))
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert max(len(li) for li in lines) <= 80
    assert "…" not in done.stdout
    names = json.loads(cli("param", "list", "--format", "json", "--port", fake.url).stdout)
    for row in names:  # each name whole, on one line of the table
        assert any(f" {row['name']} " in li for li in lines), row["name"]


# --- a full stdout ----------------------------------------------------------------------------

@pytest.mark.parametrize("args", [
    ["budget"], ["budget", "--format", "json"], ["config"], ["ports", "--all"],
    ["--help"], ["param", "list"], ["param", "list", "--format", "csv"],
    ["param", "dump", "-"],
], ids=lambda a: " ".join(a))
def test_a_full_stdout_is_one_line_and_exit_1(
    args: list[str], fake_board: Callable[..., BoardThread]
) -> None:
    if args[0] == "param":
        args = [*args, "--port", fake_board().url]
    with open("/dev/full", "w") as full:
        done = cli(*args, stdout=full)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    errors = [li for li in done.stderr.splitlines() if li.startswith("fpgalink-cli: error:")]
    assert len(errors) == 1 and "No space left" in errors[0], done.stderr


@pytest.mark.parametrize("args", [
    ["--version"], ["param", "get", "TsTimerPeriod"],
    ["send", "PG", "--hex", "0100", "--reply", "PA"],
    ["monitor", "--duration", "0.3", "--format", "jsonl"],
    ["step", "--channel", "A", "--to", "20", "--pre", "0.05", "--hold", "0.2"],
    ["drive", "--v", "0.05", "--for", "0.2"], ["goto", "0.02", "0"],
    ["router", "--port", "emu://"], ["codegen", "c", "{tmp}/c"],
], ids=lambda a: " ".join(a[:2]))
def test_every_other_command_on_a_full_stdout_is_one_line_and_exit_1(
        args: list[str], tmp_path: Path) -> None:
    """The rest of the commands (issue 26: every command), each against the built-in
    emulator; whatever it prints first meets the full disk."""
    args = [a.format(tmp=tmp_path) for a in args]
    with open("/dev/full", "w") as full:
        done = cli(*args, "--port", "emu://", stdout=full) \
            if args[0] in ("step", "param", "send") else cli(*args, stdout=full)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    errors = [li for li in done.stderr.splitlines() if li.startswith("fpgalink-cli: error:")]
    assert errors == ["fpgalink-cli: error: cannot write to stdout: No space left on device"], \
        done.stderr


@pytest.mark.parametrize(("program", "args"), [
    ("fpgaemu", ["--help"]), ("fpgaemu", ["--version"]), ("fpgaemu", ["serve", "--pty"]),
    ("fpgaemu", ["serve", "--tcp", "127.0.0.1:0"]),
    ("fpgalink-ros2", ["--help"]), ("fpgalink-ros2", ["--version"]),
], ids=lambda a: a if isinstance(a, str) else " ".join(a))
def test_the_other_programs_on_a_full_stdout_are_one_line_and_exit_1(
        program: str, args: list[str]) -> None:
    """fpgaemu (click's help into it was a traceback; serve's ready line too) and
    fpgalink-ros2 (argparse dropped the error and exited 0) agree with fpgalink-cli."""
    script = Path(sys.executable).parent / program
    module = {"fpgaemu": "fpgaemu", "fpgalink-ros2": "fpgalink.ros2"}[program]
    command = [str(script)] if script.exists() else [sys.executable, "-m", module]
    with open("/dev/full", "w") as full:
        done = subprocess.run([*command, *args], stdout=full, stderr=subprocess.PIPE,
                              text=True, cwd=ROOT, env=cli_env(), timeout=60)
    assert done.returncode == 1, done.stderr
    assert done.stderr == f"{program}: error: cannot write to stdout: No space left on device\n"


# --- help, usage, negative numbers ------------------------------------------------------------

@pytest.mark.parametrize("args", [[], ["param"]], ids=["fpgalink-cli", "param"])
def test_a_bare_group_prints_its_help_and_exits_0(args: list[str]) -> None:
    done = cli(*args)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("Usage: fpgalink-cli") and "Commands:" in done.stdout
    assert done.stderr == ""


def test_fpgaemu_bare_agrees() -> None:
    script = Path(sys.executable).parent / "fpgaemu"
    command = [str(script)] if script.exists() else [sys.executable, "-m", "fpgaemu"]
    done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, env=cli_env(),
                          timeout=60)
    assert done.returncode == 0 and done.stdout.startswith("Usage:")


def test_a_usage_error_points_at_the_subcommands_help() -> None:
    done = cli("param", "set")
    assert done.returncode == 2
    assert_one_line_error(done.stderr, "Missing argument", "see fpgalink-cli param set -h")


@pytest.mark.parametrize(("args", "needle"), [
    # -0.3 is taken as X, so the error is about the option after it, not "No such option -0".
    (["goto", "-0.3", "0", "--tolerance", "99"], "--tolerance"),
    (["goto", "0", "-1e-1", "--tolerance", "99"], "--tolerance"),
    (["drive", "--omega", "-10", "--v", "99"], "--v"),
    (["goto", "-0.3", "0", "--bogus"], "No such option '--bogus'"),
])
def test_negative_numbers_as_written(args: list[str], needle: str) -> None:
    done = cli(*args)
    assert done.returncode == 2
    assert_one_line_error(done.stderr, needle)
    assert "-0" not in done.stderr.split("error:")[1].split("(see")[0].replace("-0.3", "")


def test_goto_a_negative_goal_arrives() -> None:
    done = cli("goto", "-0.2", "0", "--format", "json", timeout=90)
    assert done.returncode == 0, done.stderr
    document = json.loads(done.stdout)
    assert document["arrived"] is True and document["goal"]["x_m"] == -0.2
    assert document["odometry"]["x_m"] < -0.1


# --- an explicit --port wins over the file's board --------------------------------------------

def test_port_on_the_command_line_wins_over_the_files_board(
    fake_board: Callable[..., BoardThread], tmp_path: Path
) -> None:
    fake = fake_board(values={(2, 0): 0, (1, 0): 3})
    (tmp_path / "fpgalink.toml").write_text(
        'board = "L"\n[ports]\nL = "/dev/nonexistent-L"\nR = "/dev/nonexistent-R"\n')
    done = cli("param", "get", "TsTimerPeriod", "--port", fake.url, cwd=tmp_path,
               env={**cli_env(), "PYTHONPATH": f"{ROOT / 'src'}{os.pathsep}{ROOT}"})
    assert done.returncode == 0, done.stderr
    assert done.stdout == "3\n"
    done = cli("config", "--format", "json", "--port", fake.url, cwd=tmp_path,
               env={**cli_env(), "PYTHONPATH": f"{ROOT / 'src'}{os.pathsep}{ROOT}"})
    settings = json.loads(done.stdout)["settings"]
    assert settings["board"]["value"] is None
    assert "set aside" in settings["board"]["source"]


# --- completion -------------------------------------------------------------------------------

def _complete(*words: str) -> list[str]:
    env = cli_env(_FPGALINK_CLI_COMPLETE="bash_complete", COMP_WORDS=" ".join(
        ["fpgalink-cli", *words]), COMP_CWORD=str(len(words)))
    done = cli(env=env)
    return done.stdout.splitlines()


def test_completion_offers_files_for_param_load_and_ports_for_port() -> None:
    offered = _complete("param", "load", "")
    assert "file," in offered and "plain,seed-high" in offered
    offered = _complete("param", "list", "--port", "")
    assert "plain,emu://" in offered and "file," in offered


# --- SIGTERM as Ctrl-C ------------------------------------------------------------------------

def test_step_on_sigterm_disables_the_board_and_exits_143(
    fake_board: Callable[..., BoardThread]
) -> None:
    fake = fake_board()
    step = subprocess.Popen([*SCRIPT, "step", "--channel", "A", "--to", "45", "--pre", "0.2",
                             "--hold", "60", "--port", fake.url], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT, env=cli_env())
    def names() -> list[str]:
        return [type(m).__name__ for m in fake.board.received]

    try:
        wait_until_sync(lambda: "Enable" in names(), timeout=30)
        step.send_signal(signal.SIGTERM)
        _, stderr = step.communicate(timeout=30)
    finally:
        if step.poll() is None:
            step.kill()
    assert step.returncode == 143, stderr
    assert "SIGTERM" in stderr and "disabled" in stderr and "Traceback" not in stderr
    received = names()
    assert "Disable" in received[received.index("Enable"):]  # RD after the RE


def test_step_beyond_the_wheels_reach_says_so() -> None:
    done = cli("step", "--channel", "A", "--to", "1e9", "--pre", "0.05", "--hold", "0.2",
               "--port", "emu://")
    assert "beyond the wheel's reach" in done.stderr, done.stderr


def test_fpgaemu_serve_help_keeps_the_fault_table() -> None:
    from fpgaemu.faults import FAULT_HELP

    script = Path(sys.executable).parent / "fpgaemu"
    command = [str(script)] if script.exists() else [sys.executable, "-m", "fpgaemu"]
    done = subprocess.run([*command, "serve", "--help"], capture_output=True, text=True,
                          cwd=ROOT, env=cli_env(COLUMNS="100"), timeout=60)
    assert done.returncode == 0, done.stderr
    shown = [line.strip() for line in done.stdout.splitlines()]
    for row in FAULT_HELP.splitlines():  # each row of the table on a line of its own
        assert row.strip() in shown, row


@pytest.mark.skipif(shutil.which("script") is None, reason="needs util-linux's script (a tty)")
def test_monitor_on_an_80_column_terminal_tells_the_boards_ports_apart(tmp_path: Path) -> None:
    links = {name: tmp_path / f"fpga-board-with-a-long-name-{name}" for name in "LR"}
    with served("--pty", "--boards", "2",
                *[a for name, path in links.items() for a in ("--link", f"{name}={path}")]):
        command = " ".join([*SCRIPT, "monitor", "--duration", "1",
                            *[a for name, path in links.items()
                              for a in ("--port", f"{name}={path}")]])
        done = subprocess.run(["script", "-qec", f"stty cols 80 rows 60; {command}",
                               "/dev/null"], capture_output=True, text=True, cwd=ROOT,
                              env=cli_env(COLUMNS="80"), timeout=60)
        assert done.returncode == 0, done.stdout + done.stderr
    screen = re.sub(r"\x1b\[[0-9;?]*[a-zA-Z]", "", done.stdout)
    # The last frame of the live view (a line said on stderr after it, such as telemetry
    # stopping on a loaded machine, is the terminal's to wrap).
    last = screen[screen.rindex("Link"):]
    last = last[:last.index("Ctrl-C stops") + len("Ctrl-C stops")]
    rows = [li for li in last.splitlines() if li.startswith("│")]
    assert [li for li in last.splitlines() if len(li) > 80] == [], last
    assert "…" not in last
    ports: dict[str, str] = {}
    board = ""
    for row in rows:  # the port column folds: a board's whole path, in pieces
        cells = [c.strip() for c in row.split("│")]
        board = cells[1] or board
        ports[board] = ports.get(board, "") + cells[2]
    assert ports == {name: str(path) for name, path in links.items()}, last


@pytest.mark.parametrize("args", [["record", "-"], ["record", "-", "--csv"]])
def test_record_to_dash_says_it_writes_a_file(args: list[str], tmp_path: Path) -> None:
    """Issue 26's rough edges: ``record -`` made a file named "-" where ``param dump -``
    means stdout; now one line pointing at monitor's streams, and no file."""
    done = cli(*args, "--duration", "0.2", cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, "not stdout", "monitor --format csv|jsonl")
    assert not (tmp_path / "-").exists()


@pytest.mark.parametrize("args", [["drive", "--for", "0.2", "--record", "-"],
                                  ["goto", "0.1", "0", "--plot", "-"],
                                  ["drive", "--for", "0.2", "--rosbag2", "-"]])
def test_a_robot_commands_files_are_never_dash(args: list[str], tmp_path: Path) -> None:
    """``drive``/``goto --record -`` made a file named "-": refused before anything runs."""
    done = cli(*args, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert "not '-'" in done.stderr and "Traceback" not in done.stderr
    assert done.stderr.count("\n") == 1
    assert not (tmp_path / "-").exists()
