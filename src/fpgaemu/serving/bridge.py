"""What stands between the board's TX pin and a host's port: a USB-UART bridge.

A host never sees a UART's bytes one stop bit at a time. The CmodA7's FT2232H gathers what
the line brings and hands it over USB when its buffer fills or its latency timer runs out
(docs/hardware.md asks for 1 ms); bridges that flush when the line idles hand over a frame
as it ends. Serve used to hand out whatever had ended by each of its wake-ups, and it wakes
for the board's own deadlines too, so a host read most frames in two parts: two wake-ups
and two reads for one message that can be used only whole.

:class:`TxBridge` hands a frame on whole once its last stop bit has ended (with every other
frame that ended since: a serve woken late hands on several at once), and a frame still on
the line no later than :data:`BRIDGE_LATENCY_S` after its oldest byte ended: the FTDI
latency timer at the setting docs/hardware.md asks for, which only a frame longer than 1 ms
of line ever meets. Counted in the board's time, so a starved serve catching up hands
frames on whole all the same. A byte is never handed on before its stop bit has ended, and
none is dropped here: what has ended waits on the board's TX line, as in the bridge's
buffer (a host that does not read is the endpoint's backlog's to judge).
"""

from __future__ import annotations

from fpgaemu.serving.pacing import PacedBoard
from fpgaemu.timeline import CLOCK_HZ

__all__ = ["BRIDGE_LATENCY_S", "TxBridge"]

#: The longest a byte waits in the bridge while its frame is still on the line (the
#: FT2232H's latency timer at 1 ms, as docs/hardware.md asks of a real board's port).
BRIDGE_LATENCY_S = 0.001


class TxBridge:
    """The board's TX bytes, handed on a frame whole at a time."""

    def __init__(self, paced: PacedBoard, latency_s: float = BRIDGE_LATENCY_S) -> None:
        self.paced = paced
        self.latency_cycles = round(latency_s * CLOCK_HZ)
        self.handovers = 0  #: times bytes were handed on (a host's reads, at most)

    def take(self) -> bytes:
        """The bytes to hand on now (``b""``: none): every frame that has ended whole since
        the last call; and what has ended of the frame still on the pin once its oldest
        byte has waited the latency bound (a frame longer than that, or a slow line)."""
        out = self.paced.take_bytes(whole_runs=True)
        oldest = self.paced.board.uartwrite.oldest_unread
        if oldest is not None and self.paced.board.now >= oldest + self.latency_cycles:
            out += self.paced.take_bytes()
        if out:
            self.handovers += 1
        return out

    def next_wake(self) -> float | None:
        """When the latency bound runs out for the frame on the pin (``None``: nothing
        sent and unread). Its end, usually sooner, is the board's own wake-up already."""
        oldest = self.paced.board.uartwrite.oldest_unread
        return None if oldest is None else self.paced.time_of(oldest + self.latency_cycles + 1)
