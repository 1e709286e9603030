"""Putting a whole board together: the communication path and I/O blocks
(:class:`~fpgaemu.board.Board`), the MicroBlaze software
(:class:`~fpgaemu.firmware.Firmware`, or the C core: :class:`~fpgaemu.cfirmware.CFirmware`),
the motors and wheels (:class:`~fpgaemu.motor.Motors`)
and any injected faults — as ``fpgaemu serve`` and ``emu://`` build it."""

from __future__ import annotations

from typing import Any
from urllib.parse import parse_qs, urlsplit

from fpgaemu.board import Board, BoardConfig
from fpgaemu.faults import parse_faults
from fpgaemu.firmware import attach_firmware
from fpgaemu.motor import GEARS, DrivenMotors, Motors
from fpgaemu.uart import DEFAULT_BAUD, UART_RX_MODES

__all__ = ["EMU_OPTIONS", "FIRMWARES", "UART_RX_MODES", "board_from_url", "build_board",
           "parse_emu_options", "seed_option"]

#: The query options an ``emu://`` URL understands.
EMU_OPTIONS = ("seed", "gear", "fault", "tx_gap", "uart_rx", "firmware")
#: The MicroBlaze software: the Python model, or the C core (firmware/) through cffi.
FIRMWARES = ("python", "c")


def build_board(
    *,
    baud: int = DEFAULT_BAUD,
    seed: int = 0,
    gear: str = "high",
    settings: dict[str, Any] | None = None,
    faults: list[str] | None = None,
    tx_byte_gap: int = 0,
    current_noise_a: float = 0.0,
    firmware: str = "python",
    wheels: str = "identified",
    uart_rx: str = "edge",
    identity: bool = True,
    declarations: int | None = None,
) -> Board:
    """A complete board. ``settings`` are initial parameter values by name
    (``{"Kp_Wheel_PidA": 9.0}``), validated as the firmware validates a ``PS``; ``faults``
    are ``--fault`` specs (docs/reliability.md); ``tx_byte_gap`` the idle cycles after each
    byte ``uartwrite`` sends back to back (:class:`~fpgaemu.board.BoardConfig`);
    ``current_noise_a`` the Hall sensors' Gaussian noise (A, seeded); ``uart_rx`` how the
    receiver finds a start bit (``edge`` or ``level``, :data:`UART_RX_MODES`); ``wheels``
    what turns the wheels: ``"identified"`` (the seed's identified plant,
    :class:`~fpgaemu.motor.Motors`) or ``"driven"`` (motors as torque sources for a body's
    physics, :class:`~fpgaemu.motor.DrivenMotors`); ``firmware`` the MicroBlaze software,
    ``"python"`` (the model) or ``"c"`` (the C core, built on first use;
    :class:`~fpgaemu.cfirmware.CFirmwareUnavailable` without a C compiler); ``identity``
    False: the Python model as a seed board, which does not know ``IQ`` (counts it, answers
    nothing: "seed protocol, identity unknown"); ``declarations`` the hash its ``IA`` says
    instead of this declaration's (a firmware built from another one). ``ValueError`` for
    anything invalid."""
    if firmware not in FIRMWARES:
        raise ValueError(f"firmware must be one of {', '.join(FIRMWARES)}, got {firmware!r}")
    if gear not in GEARS:
        raise ValueError(f"gear must be one of {', '.join(sorted(GEARS))}, got {gear!r}")
    if uart_rx not in UART_RX_MODES:
        raise ValueError(f"uart_rx must be {' or '.join(UART_RX_MODES)}, got {uart_rx!r}")
    if (not identity or declarations is not None) and firmware == "c":
        raise ValueError("the C core answers IQ with the hash it was generated from: a seed "
                         "board, or one claiming another declaration, is the Python model")
    wanted = parse_faults(faults or [])
    config = BoardConfig(baud=baud, seed=seed, rx_faults=wanted.line("rx"),
                         tx_faults=wanted.line("tx"), tx_byte_gap=tx_byte_gap,
                         uart_rx=uart_rx)
    board = Board(config)
    if wheels not in ("identified", "driven"):
        raise ValueError(f"wheels must be 'identified' or 'driven', got {wheels!r}")
    if firmware == "c":
        from fpgaemu.cfirmware import attach_c_firmware

        attach_c_firmware(board, settings or {})
    else:
        attach_firmware(board, settings or {}, identity=identity, declarations=declarations)
    motors = Motors if wheels == "identified" else DrivenMotors
    board.add_peripheral("motors", motors(gear, current_noise_a))
    board.add_peripheral("faults", wanted.board_faults())
    return board


def parse_emu_options(query: str, known: tuple[str, ...], what: str) -> dict[str, list[str]]:
    options = parse_qs(query, keep_blank_values=True)
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise ValueError(f"unknown {what} option(s) {unknown}; known: {list(known)}")
    return options


def seed_option(options: dict[str, list[str]]) -> int:
    text = options.get("seed", ["0"])[-1]
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"emu:// seed must be an integer, got {text!r}") from None


def board_from_url(url: str, baud: int) -> Board:
    """``emu://?seed=3&gear=low&fault=drop-frames=PS:1&tx_gap=2&uart_rx=level&firmware=c`` → a board
    (``fault`` repeats)."""
    parts = urlsplit(url)
    if parts.scheme != "emu" or parts.netloc or parts.path not in ("", "/"):
        raise ValueError(f"expected emu:// with optional ?{'&'.join(EMU_OPTIONS)} options")
    options = parse_emu_options(parts.query, EMU_OPTIONS, "emu://")
    gap_text = options.get("tx_gap", ["0"])[-1]
    if not gap_text.isdigit():
        raise ValueError(f"emu:// tx_gap must be a whole number of cycles, got {gap_text!r}")
    return build_board(baud=baud, seed=seed_option(options),
                       gear=options.get("gear", ["high"])[-1],
                       faults=options.get("fault", []), tx_byte_gap=int(gap_text),
                       uart_rx=options.get("uart_rx", ["edge"])[-1],
                       firmware=options.get("firmware", ["python"])[-1])
