"""What the truth stream says of a board (docs/emulator.md §17): its last tick as its ``TM``
stamps it, what the firmware sampled then, the PWM and enable now, the parameters."""

from __future__ import annotations

from typing import Any

from fpgaemu.board import Board
from fpgaemu.timeline import CLOCK_HZ
from fpgalink.protocol import PARAMETERS

__all__ = ["board_record"]

PARAMETERS_BY_ID = {p.id: p for p in PARAMETERS}


def board_record(board: Board) -> dict[str, Any]:
    """A board's state for the truth stream: the last tick (as its TM stamps it), the
    speeds and encoder counts the firmware sampled then (what that TM carries), the wheels'
    references now, the PWM applied now (global_enable gates it in logic: 0 from the cycle
    enable fell), the enable, when the last RE arrived and when and why enable last fell,
    the parameters."""
    firmware: Any = board.peripherals["firmware"]
    enable_cycle = board.uartcommand.last_enable_cycle
    disable = board.uartcommand.last_disable
    return {
        "t_us": ((firmware.last_tick - board.powered_at) // 100) & 0xFFFF_FFFF,
        "speed_a": firmware.channels[1].speed, "speed_b": firmware.channels[2].speed,
        "position_a": firmware.channels[1].position,
        "position_b": firmware.channels[2].position,
        # deg/s (N·m under current control): what the firmware's loops are asked now
        "reference_a": firmware.channels[1].reference,
        "reference_b": firmware.channels[2].reference,
        "pwm_a": board.channels[1].pwm.applied_duty,
        "pwm_b": board.channels[2].pwm.applied_duty,
        "enabled": board.global_enable,
        "now_s": board.now / CLOCK_HZ,
        "last_re_s": None if enable_cycle is None else enable_cycle / CLOCK_HZ,
        "disabled_s": None if disable is None else disable[0] / CLOCK_HZ,
        "disabled_by": None if disable is None else disable[1].value,
        "params": {PARAMETERS_BY_ID[pid].full_name(ch): value
                   for (pid, ch), value in firmware.values.items()},
    }

