"""The C firmware's co-simulation itself (fpgaemu.cfirmware): how it is chosen, built and
bound; that it idles as the Python model does; and what happens without a C compiler."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from fpgaemu.build import board_from_url, build_board
from fpgaemu.cfirmware import CFirmware
from fpgaemu.firmware import HW_CURRENT_KP, SW_CURRENT_KP, Firmware
from fpgaemu.motor import MotorConstants
from fpgaemu.timeline import ms
from tests.fpgaemu.test_golden_trace import rv
from tests.support.firmwares import require_c_firmware


@pytest.fixture(autouse=True)
def _c() -> None:
    require_c_firmware()


def test_emu_url_and_build_board_choose_the_firmware() -> None:
    assert isinstance(board_from_url("emu://?firmware=c", 1_000_000).peripherals["firmware"],
                      CFirmware)
    assert isinstance(board_from_url("emu://?seed=2", 1_000_000).peripherals["firmware"],
                      Firmware)
    with pytest.raises(ValueError, match="firmware must be one of python, c"):
        build_board(firmware="rust")


def test_initial_settings_are_checked_as_a_ps_and_applied() -> None:
    board = build_board(firmware="c", settings={"Kp_Wheel_PidA": 9.0, "TsTimerPeriod": 4})
    firmware = board.peripherals["firmware"]
    assert isinstance(firmware, CFirmware)
    assert firmware.value("Kp_Wheel_PidA") == 9.0 and firmware.channels[1].pid.gains.kp == 9.0
    assert board.timer.period_cycles == ms(4)
    for bad, code in (({"TsTimerPeriod": 0}, "value out of range"),
                      ({"TsTimerPeriod": 2.5}, "wrong value type"),
                      ({"Ti_Wheel_PidB": 0.0}, "value out of range")):
        with pytest.raises(ValueError, match=code):
            build_board(firmware="c", settings=bad)


def test_the_c_defaults_for_the_current_loops_are_the_emulated_motors() -> None:
    # The emulator passes its motor model's constants; a real board's port uses
    # fw_default_config(), which must be the same numbers for the same motor.
    from fpgaemu.cfirmware import load_firmware

    _, lib = load_firmware()
    config = lib.fw_default_config()
    motor = MotorConstants()
    assert config.sw_current_kp == SW_CURRENT_KP and config.hw_current_kp == HW_CURRENT_KP
    assert config.electrical_tau == motor.inductance_h / motor.resistance_ohm


def test_a_board_at_rest_skips_its_ticks_as_the_python_model_does() -> None:
    fast = build_board(firmware="c")
    full = build_board(firmware="c")
    firmware = full.peripherals["firmware"]
    assert isinstance(firmware, CFirmware)
    firmware.skip_quiescent_ticks = False
    for board in (fast, full):
        board.run_for(0.3)
    fast_fw = fast.peripherals["firmware"]
    assert isinstance(fast_fw, CFirmware)
    assert fast.quiescent and not full.quiescent
    assert fast_fw.timing.periods == firmware.timing.periods == 300
    assert fast.read_host_bytes_timed() == full.read_host_bytes_timed()  # the E frames


def test_a_python_error_inside_a_hal_call_surfaces() -> None:
    # It cannot unwind through the C frames: it is kept and raised when the call returns,
    # never swallowed with a default value. The PWM stage's model (what the HAL's duty
    # write drives) fails once the board is enabled (a bug in a model, not in the C).
    board = build_board(firmware="c")
    pwm = board.channels[1].pwm

    def broken(cycle: int) -> None:
        if pwm.global_enable:
            raise RuntimeError("the PWM stage's model broke")

    pwm.on_change(broken)
    board.host_write(b"SREP" + rv(1, 40.0, 40.0))
    with pytest.raises(RuntimeError, match="the PWM stage's model broke"):
        board.run_for(0.01)


def test_without_a_c_compiler_the_c_firmware_says_so_and_python_still_runs(
        tmp_path: Path) -> None:
    empty = tmp_path / "bin"
    empty.mkdir()
    probe = ("from fpgaemu.build import build_board\n"
             "build_board().run_for(0.01)\n"
             "try:\n    build_board(firmware='c')\n"
             "except ValueError as exc:\n    print('refused:', exc)\n")
    env = {**os.environ, "PATH": str(empty), "FPGAEMU_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("CC", None)
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          env=env, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert "refused:" in done.stdout and "no C compiler found" in done.stdout
