"""The CLI where people put things (issue 16): connection options before or after the
command, ``--board`` among several, a config file with a visible precedence, one-line usage
errors, lazy command loading with the help declared once, completion, and the built-in
emulator's short memory said out loud."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import click
import pytest

from fpgalink.cli import COMMANDS, cli
from tests.fpgalink.cli.test_errors import assert_one_line_error
from tests.support.cli import Board, BoardThread, cli_env, run_cli

pytestmark = pytest.mark.timeout(60)


def test_connection_options_before_the_command(fake_board: Callable[..., BoardThread]) -> None:
    fake = fake_board(values={(2, 0): 0, (1, 0): 4})
    done = run_cli("--port", fake.url, "-v", "--retries", "2", "param", "get", "TsTimerPeriod")
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "4"


def test_an_option_after_the_command_wins_over_one_before(
    fake_board: Callable[..., BoardThread], tmp_path: Path
) -> None:
    fake = fake_board()
    done = run_cli("--port", str(tmp_path / "ttyNONE"), "param", "get", "TsTimerPeriod",
                   "--port", fake.url)
    assert done.returncode == 0, done.stderr


def test_board_picks_one_of_several_and_the_error_says_so(
    fake_board: Callable[..., BoardThread]
) -> None:
    left, right = fake_board(values={(1, 0): 2}), fake_board(values={(1, 0): 3})
    env = cli_env(FPGALINK_PORT=f"L={left.url} R={right.url}")
    done = run_cli("param", "get", "TsTimerPeriod", env=env)
    assert done.returncode == 2
    assert_one_line_error(done.stderr, "2 are configured", "L, R", "FPGALINK_PORT",
                          "--board NAME")
    assert run_cli("--board", "R", "param", "get", "TsTimerPeriod", env=env).stdout == "3\n"
    done = run_cli("param", "get", "TsTimerPeriod", env={**env, "FPGALINK_BOARD": "L"})
    assert done.stdout == "2\n", done.stderr
    done = run_cli("param", "get", "TsTimerPeriod", "--board", "X", env=env)
    assert done.returncode == 2
    assert_one_line_error(done.stderr, "--board X", "no such board", "L, R")


def test_config_file_precedence_and_sources(
    fake_board: Callable[..., BoardThread], tmp_path: Path
) -> None:
    fake = fake_board(values={(1, 0): 6})
    (tmp_path / "fpgalink.toml").write_text(
        f'baud = 115200\ntimeout = 0.2\nboard = "R"\n[ports]\nL = "/nonexistent/L"\n'
        f'R = "{fake.url}"\n', encoding="utf-8")
    done = run_cli("param", "get", "TsTimerPeriod", cwd=tmp_path)  # found in the cwd
    assert done.returncode == 0, done.stderr
    assert done.stdout == "6\n"
    done = run_cli("--timeout", "0.3", "config", "--format", "json", cwd=tmp_path,
                   env=cli_env(FPGALINK_BAUD="2000000"))
    assert done.returncode == 0, done.stderr
    shown = json.loads(done.stdout)
    where = f"config file {tmp_path / 'fpgalink.toml'}"
    assert shown["config_file"] == str(tmp_path / "fpgalink.toml")
    settings = shown["settings"]
    assert settings["port"] == {"value": [{"name": "L", "url": "/nonexistent/L"},
                                          {"name": "R", "url": fake.url}], "source": where}
    assert settings["board"] == {"value": "R", "source": where}
    assert settings["baud"] == {"value": 2000000, "source": "environment FPGALINK_BAUD"}
    assert settings["timeout_s"] == {"value": 0.3, "source": "command line"}
    assert settings["retries"] == {"value": 8, "source": "default"}
    # The environment's port beats the file's; the command line beats both.
    done = run_cli("config", "--port", "emu://", cwd=tmp_path,
                   env=cli_env(FPGALINK_PORT="/nonexistent/env"))
    assert "emu://" in done.stdout and "(command line)" in done.stdout


def test_config_file_in_the_user_config_directory(tmp_path: Path) -> None:
    home = tmp_path / "xdg"
    (home / "fpgalink").mkdir(parents=True)
    (home / "fpgalink" / "fpgalink.toml").write_text('port = "/dev/serial/by-id/x"\n')
    done = run_cli("config", cwd=tmp_path, env={**cli_env(), "XDG_CONFIG_HOME": str(home)})
    assert done.returncode == 0, done.stderr
    assert "/dev/serial/by-id/x" in done.stdout and str(home) in done.stdout


@pytest.mark.parametrize(("text", "needles"), [
    ("speed = 3\n", ["unknown key 'speed'"]),
    ("baud = 'fast'\n", ["baud must be a whole number"]),
    ("timeout = inf\n", ["timeout must be a number of seconds"]),
    ("port = 3\n", ["port must be a URL"]),
    ("port = [\n", ["not valid TOML"]),
])
def test_a_bad_config_file_is_one_line_naming_the_key(
    tmp_path: Path, text: str, needles: list[str]
) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    done = run_cli("--config", str(path), "param", "get", "TsTimerPeriod")
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, str(path), *needles)


@pytest.mark.parametrize(("args", "help_of"), [
    (["param", "get"], "fpgalink-cli param get -h"), (["nosuchcommand"], "fpgalink-cli -h"),
    (["param", "get", "TsTimerPeriod", "--bogus"], "fpgalink-cli param get -h"),
    (["--port"], "fpgalink-cli -h"), (["monitor", "--format", "xml"], "fpgalink-cli monitor -h"),
])
def test_usage_errors_are_one_line_exit_2(args: list[str], help_of: str) -> None:
    # Each points at the help of the command it is about (issue 26).
    done = run_cli(*args)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, f"(see {help_of})")


def test_the_command_list_matches_each_commands_own_help() -> None:
    # The group lists commands without importing them; the text is declared twice, so check.
    group = cli
    assert isinstance(group, click.Group)
    for name, (module, attribute, summary) in COMMANDS.items():
        command = getattr(importlib.import_module(module), attribute)
        assert isinstance(command, click.Command)
        first = (command.help or "").strip().splitlines()[0]
        assert summary == first, name


def test_help_lists_commands_without_importing_them() -> None:
    done = run_cli("--help")
    assert done.returncode == 0
    for name in COMMANDS:
        assert f"  {name} " in done.stdout
    probe = ("import json, sys, fpgalink.cli as c\n"
             "try:\n    c.cli.main(['--help'], standalone_mode=False)\nexcept SystemExit:\n"
             "    pass\nprint(json.dumps(sorted(m for m in sys.modules if m.startswith("
             "('fpgalink.cli.', 'rich', 'mcap', 'asyncio', 'construct', 'numpy')))))")
    loaded = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                            env=cli_env(), timeout=30, check=True).stdout.splitlines()[-1]
    assert json.loads(loaded) == ["fpgalink.cli.options", "fpgalink.cli.output",
                                  "fpgalink.cli.settings"]


def _complete(*words: str, **env: str) -> list[str]:
    """What bash completion offers for the last of ``words`` (click's protocol)."""
    done = subprocess.run(
        [sys.executable, "-c", "from fpgalink.cli import main; main()"],
        capture_output=True, text=True, timeout=30,
        env=cli_env(_FPGALINK_CLI_COMPLETE="bash_complete", COMP_CWORD=str(len(words)),
                    COMP_WORDS=" ".join(["fpgalink-cli", *words]), **env))
    return [line.split(",", 1)[1] for line in done.stdout.splitlines() if "," in line]


def test_shell_completion_knows_commands_parameters_and_boards() -> None:
    assert _complete("rec") == ["record"]
    names = _complete("param", "get", "Kp_W")
    assert names == ["Kp_Wheel_Pid", "Kp_Wheel_PidA", "Kp_Wheel_PidB"]  # base name + -c
    # Board names come from the configuration (here the environment).
    assert _complete("param", "get", "--board", "", FPGALINK_PORT="L=a R=b") == ["L", "R"]


def test_the_built_in_emulator_says_it_forgets(board: Board) -> None:
    done = run_cli("param", "set", "TsTimerPeriod", "3", "--port", board.url)
    assert done.returncode == 0, done.stderr
    said = "lives only for this command" in done.stderr
    assert said == (board.kind == "emu"), done.stderr
    if said:
        assert "fpgaemu serve --pty --link" in done.stderr
