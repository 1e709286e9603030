"""What stands between the board's TX pin and a host's port: a USB-UART bridge.

A host never sees a UART's bytes one stop bit at a time. The CmodA7's FT2232H gathers what
the line brings and hands it over USB when its buffer fills or its latency timer runs out
(docs/hardware.md asks for 1 ms); bridges that flush when the line idles hand over a frame
as it ends. Serve used to hand out whatever had ended by each of its wake-ups, and it wakes
for the board's own deadlines too, so a host read most frames in two parts: two wake-ups
and two reads for one message that can be used only whole.

:class:`TxBridge` hands bytes on when the TX line idles (the end of a frame, or of a burst
of frames sent back to back), and while the line stays busy, no later than
:data:`BRIDGE_LATENCY_S` after the first byte held: the FTDI latency timer at the setting
docs/hardware.md asks for, counted in the board's time (a starved serve catching up hands a
frame on whole all the same). A byte is never handed on before its stop bit has ended, and
none is dropped here (a host that does not read is the endpoint's backlog's to judge).
"""

from __future__ import annotations

from fpgaemu.serving.pacing import PacedBoard
from fpgaemu.timeline import CLOCK_HZ

__all__ = ["BRIDGE_LATENCY_S", "TxBridge"]

#: The longest a byte waits in the bridge while the line stays busy (the FT2232H's latency
#: timer at 1 ms, as docs/hardware.md asks of a real board's port).
BRIDGE_LATENCY_S = 0.001


class TxBridge:
    """The board's TX bytes, handed on whole frames (or bursts) at a time."""

    def __init__(self, paced: PacedBoard, latency_s: float = BRIDGE_LATENCY_S) -> None:
        self.paced = paced
        self.latency_cycles = round(latency_s * CLOCK_HZ)
        self._held = bytearray()
        self._held_since: int | None = None  #: the board's cycle when the oldest was held
        self.handovers = 0  #: times bytes were handed on (a host's reads, at most)

    def take(self) -> bytes:
        """The bytes to hand on now (``b""``: none): what ended on the line since the last
        call, held while a frame is still on the pin, unless held for the latency bound."""
        out = self.paced.take_bytes()
        now = self.paced.board.now
        if out:
            if not self._held:
                self._held_since = now
            self._held += out
        if not self._held:
            return b""
        since = self._held_since
        if self.paced.tx_busy() and since is not None and now < since + self.latency_cycles:
            return b""
        return self._hand_on()

    def discard(self) -> int:
        """The port went (unplugged): what the bridge held is gone. Returns how many bytes."""
        lost = len(self._held)
        self._held.clear()
        self._held_since = None
        return lost

    @property
    def held(self) -> int:
        """Bytes ended on the line and not yet handed on."""
        return len(self._held)

    def next_wake(self) -> float | None:
        """When held bytes must go even though the line is still busy (``None``: none
        held). The end of the frame on the pin is the board's own wake-up already."""
        since = self._held_since
        return None if not self._held or since is None \
            else self.paced.time_of(since + self.latency_cycles + 1)

    def _hand_on(self) -> bytes:
        out = bytes(self._held)
        self._held.clear()
        self._held_since = None
        self.handovers += 1
        return out
