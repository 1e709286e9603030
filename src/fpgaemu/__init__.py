"""fpgaemu: cycle-level emulator of the FPGA motor-controller board.

One module per hardware block of the seed's figures (``uart``, ``uartcommand``,
``uartsend``, ``bram``, ``axi``, ``pwm``, ``encoder``, ``timer``, ``pid``), the MicroBlaze
software (``firmware``), the motors and wheels (``motor``), wired in ``board`` on the
integer-cycle ``timeline``; :func:`build_board` puts a complete board together and
``serve`` paces it to the wall clock behind a pty, a TCP port or ``emu://``.
"""

# Before any module of this package: fpgalink's package decides which build runs, compiled
# or pure Python, for both packages (fpgalink.buildinfo), and importing the protocol
# imports it.
import fpgalink.protocol  # noqa: F401
from fpgaemu.board import Board, BoardConfig, ChannelIo
from fpgaemu.build import board_from_url, build_board
from fpgaemu.firmware import Firmware
from fpgaemu.motor import Motors
from fpgaemu.timeline import CLOCK_HZ, Timeline, ms, us

__all__ = [
    "CLOCK_HZ",
    "Board",
    "BoardConfig",
    "ChannelIo",
    "Firmware",
    "Motors",
    "Timeline",
    "board_from_url",
    "build_board",
    "ms",
    "us",
]
