"""The line's backlog: how much line time waits unwritten in a link's transport, and the bound
on it (issue 37.1). What a caller can queue toward a board stays bounded whatever it does: a
counted message or parameter request is refused (:class:`~fpgalink.errors.LineBusy`, counted
in ``stats.line_busy``) while more than :data:`MAX_LINE_BACKLOG_S` waits. The link moves the
bytes, so the judgement is the link's, not the connection's: only the transport knows what it
has not written yet."""

from __future__ import annotations

import asyncio

from fpgalink.connection import LinkStats
from fpgalink.errors import LineBusy

__all__ = ["MAX_LINE_BACKLOG_S", "check_line", "line_backlog_s"]

#: A counted message or parameter request is refused (:class:`~fpgalink.errors.LineBusy`)
#: while more than this much line time (at the connection's baud) waits in the transport
#: unwritten. ``RE``, ``RD`` and references are never refused (references are superseded
#: instead).
MAX_LINE_BACKLOG_S = 0.25

#: Bits a byte takes on the line (start, 8 data bits, stop).
_BITS_PER_BYTE = 10


def line_backlog_s(transport: asyncio.BaseTransport | None, baud: int | None) -> float:
    """Seconds of line time waiting unwritten in ``transport`` at ``baud``: 0 for a transport
    that does not say (``get_write_buffer_size`` not implemented: an in-memory one, a test
    double) or a line whose rate is not known."""
    if not baud or not isinstance(transport, asyncio.WriteTransport):
        return 0.0
    try:
        return transport.get_write_buffer_size() * _BITS_PER_BYTE / baud
    except NotImplementedError:
        return 0.0


def check_line(transport: asyncio.BaseTransport | None, baud: int | None, stats: LinkStats,
               what: str) -> None:
    """Raise :class:`~fpgalink.errors.LineBusy` for ``what`` (counted in ``stats``) while
    more than :data:`MAX_LINE_BACKLOG_S` of line time waits in ``transport``."""
    waiting_s = line_backlog_s(transport, baud)
    if waiting_s > MAX_LINE_BACKLOG_S:
        stats.line_busy += 1
        raise LineBusy(f"{what} not sent: {waiting_s * 1000:.0f} ms of line time already "
                       f"waits to be written (at most {MAX_LINE_BACKLOG_S * 1000:.0f} ms)")
