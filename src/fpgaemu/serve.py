"""Serving emulated boards as devices: a pseudo-terminal or a TCP port per board, or an
in-process asyncio transport for ``emu://``, all paced to the wall clock. The public names
of :mod:`fpgaemu.serving`, gathered (each module there has one concern); ``fpgalink`` finds
:func:`open_emulated_transport` here through its ``fpgalink.transports`` entry point."""

from __future__ import annotations

from fpgaemu.serving.inprocess import (
    FAR_END_LAG_EXTRA,
    TRUTH_EXTRA,
    EmulatedTransport,
    open_emulated_transport,
)
from fpgaemu.serving.loop import PreciseEpollSelector, say, serve_loop
from fpgaemu.serving.pacing import (
    CATCH_UP_SLICE_S,
    RX_BACKLOG_BYTES,
    RX_RESUME_BYTES,
    LagReport,
    PacedBoard,
    PacedRobot,
    RobotSide,
)
from fpgaemu.serving.pty import PtyEndpoint
from fpgaemu.serving.tcp import IDLE_TIMEOUT_S, TcpEndpoint
from fpgaemu.serving.truth import MAX_TRUTH_READERS, TruthEndpoint

__all__ = [
    "CATCH_UP_SLICE_S",
    "FAR_END_LAG_EXTRA",
    "IDLE_TIMEOUT_S",
    "MAX_TRUTH_READERS",
    "RX_BACKLOG_BYTES",
    "RX_RESUME_BYTES",
    "TRUTH_EXTRA",
    "EmulatedTransport",
    "LagReport",
    "PacedBoard",
    "PacedRobot",
    "PreciseEpollSelector",
    "PtyEndpoint",
    "RobotSide",
    "TcpEndpoint",
    "TruthEndpoint",
    "open_emulated_transport",
    "say",
    "serve_loop",
]
