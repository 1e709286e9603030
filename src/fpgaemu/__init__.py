"""fpgaemu: cycle-level emulator of the FPGA motor-controller board."""

from fpgaemu.axi import AxiBus, TxQueue, TxQueueStats
from fpgaemu.board import Board, BoardConfig, Peripheral
from fpgaemu.bram import BRAM_BYTES, BlockRam
from fpgaemu.timeline import (
    CLOCK_HZ,
    EventHandle,
    Timeline,
    cycles_to_seconds,
    seconds_to_cycles,
)
from fpgaemu.uart import (
    BIT_START,
    BIT_STOP,
    DEFAULT_BAUD,
    ByteRun,
    LineFaults,
    LineStats,
    UartRead,
    UartWrite,
    cycles_per_bit,
)
from fpgaemu.uartcommand import (
    WATCHDOG_CYCLES,
    EnableCause,
    EnableChange,
    FrameFilter,
    RxInterrupt,
    UartCommand,
    UartCommandStats,
)
from fpgaemu.uartsend import TxDone, UartSend, UartSendStats, frame_bytes

__all__ = [
    "BIT_START",
    "BIT_STOP",
    "BRAM_BYTES",
    "CLOCK_HZ",
    "DEFAULT_BAUD",
    "WATCHDOG_CYCLES",
    "AxiBus",
    "BlockRam",
    "Board",
    "BoardConfig",
    "ByteRun",
    "EnableCause",
    "EnableChange",
    "EventHandle",
    "FrameFilter",
    "LineFaults",
    "LineStats",
    "Peripheral",
    "RxInterrupt",
    "Timeline",
    "TxDone",
    "TxQueue",
    "TxQueueStats",
    "UartCommand",
    "UartCommandStats",
    "UartRead",
    "UartSend",
    "UartSendStats",
    "UartWrite",
    "cycles_per_bit",
    "cycles_to_seconds",
    "frame_bytes",
    "seconds_to_cycles",
]
