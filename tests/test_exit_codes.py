"""41.12: one exit-code table for every console script (fpgalink.protocol.exitcodes), its
codes the same whichever program says them; each case through the console scripts."""

from __future__ import annotations

import textwrap
from enum import IntEnum
from pathlib import Path
from types import ModuleType

import pytest

import fpgaemu.__main__ as fpgaemu_main
import fpgalink.cli.output as cli_output
import fpgalink.ros2.__main__ as ros2_main
from fpgalink.protocol.exitcodes import ExitCode, exit_codes_help
from tests.support.scripts import script, without


def _codes(module: ModuleType) -> dict[str, object]:
    return {name: value for name, value in vars(module).items()
            if name.startswith("EXIT_") and isinstance(value, int)}


@pytest.mark.parametrize("module", [fpgaemu_main, ros2_main, cli_output])
def test_every_programs_codes_are_members_of_the_one_declaration(module: ModuleType) -> None:
    assert _codes(module) or module is cli_output
    for name, value in _codes(module).items():
        assert isinstance(value, ExitCode), f"{module.__name__}.{name} = {value!r}"
    enums = [v for v in vars(module).values() if isinstance(v, type) and
             issubclass(v, IntEnum) and "Exit" in v.__name__]
    assert all(e is ExitCode for e in enums), enums


def test_the_codes_do_not_collide() -> None:
    assert len({int(c) for c in ExitCode}) == len(ExitCode)


@pytest.mark.parametrize("program", ["fpgalink-cli", "fpgaemu", "fpgalink-ros2"])
def test_each_programs_help_gives_the_shared_table(program: str) -> None:
    args = ["serve", "--help"] if program == "fpgaemu" else ["--help"]
    done = script(program, *args)
    assert done.returncode == 0, done.stderr
    text = " ".join(done.stdout.split())
    assert "Exit codes (the same for fpgalink-cli, fpgaemu and fpgalink-ros2)" in text
    assert "8 an optional part not installed" in text
    assert "5 port missing, busy or failed" in text


def test_a_missing_cffi_is_not_installed_for_the_cli_and_serve(tmp_path: Path) -> None:
    """emu://?firmware=c without cffi said "port missing or busy" (5)."""
    env = without(tmp_path, "cffi")
    done = script("fpgalink-cli", "param", "get", "TsTimerPeriod", "--port",
                  "emu://?firmware=c", env=env)
    assert done.returncode == ExitCode.NOT_INSTALLED, done.stderr
    assert "pip install 'fpgalink[cosim]'" in done.stderr
    served = script("fpgaemu", "serve", "--pty", "--firmware", "c", env=env)
    assert served.returncode == ExitCode.NOT_INSTALLED, served.stderr
    assert "pip install 'fpgalink[cosim]'" in served.stderr


@pytest.mark.parametrize("url", ["emu://bogus", "emu://?seed=x", "emu://robot/?surface=x"])
def test_a_malformed_emulator_url_is_bad_input(url: str) -> None:
    done = script("fpgalink-cli", "param", "get", "TsTimerPeriod", "--port", url)
    assert done.returncode == ExitCode.BAD_INPUT, done.stderr
    assert done.stderr.count("error:") == 1


def test_a_missing_port_is_still_a_port_error() -> None:
    done = script("fpgalink-cli", "param", "get", "TsTimerPeriod", "--port",
                  "/dev/fpgalink-test-no-such-port")
    assert done.returncode == ExitCode.PORT, done.stderr


def test_the_node_without_ros2_is_not_installed(tmp_path: Path) -> None:
    """fpgalink-ros2 said 3 ("board refused" in the CLI) for ROS 2 not installed."""
    env = without(tmp_path, "rclpy", "diagnostic_msgs")
    done = script("fpgalink-ros2", env=env)
    assert done.returncode == ExitCode.NOT_INSTALLED, done.stderr
    assert "pip install 'fpgalink[ros2]'" in done.stderr


def test_the_help_paragraph_names_only_the_codes_asked_for() -> None:
    text = exit_codes_help((ExitCode.OK, ExitCode.PORT))
    assert text.endswith(
        "0 ok; 5 port missing, busy or failed (or a file another process is writing now).")
    assert textwrap.fill(text, 79)
