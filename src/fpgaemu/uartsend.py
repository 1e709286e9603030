"""``uartsend``: frames the message the processor left in the TX block RAM and feeds
``uartwrite``.

The processor writes the content into the TX RAM (words, little-endian), sets the length
register and pulses the send strobe. The logic emits START, each content byte (SKIP first if
it is START, STOP or SKIP), and STOP, back to back at line rate; the START's start bit goes
out in the strobe's cycle (the logic's few cycles of latency are below a bit time and not
modelled), so a frame of ``n`` wire bytes is busy for exactly ``n`` byte times.

Decisions (see ``docs/emulator.md``):

* One TX RAM, so a strobe while busy is **refused** (ignored and counted in
  ``refused_strobes``), as simple logic with a busy flag would do; firmware polls ``busy``
  or waits for the done interrupt — :class:`fpgaemu.axi.TxQueue` is that firmware helper.
* The message is read from the RAM at the strobe; writing the TX RAM while busy would
  corrupt the frame on real hardware, so it is counted (``writes_while_busy``) but the
  frame already on the wire is kept as it was.
* Lengths up to the whole RAM are sent; the receiver drops content past its limit.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from fpgaemu.bram import BlockRam
from fpgaemu.timeline import Timeline
from fpgaemu.uart import UartWrite
from fpgaemu.uartcommand import FrameFilter
from fpgalink.protocol import DEFAULT_FRAMING, Framing

__all__ = ["TxDone", "UartSend", "UartSendStats", "frame_bytes"]


@dataclass(frozen=True, slots=True)
class TxDone:
    """The last stop bit of a frame has ended; the module is idle again."""

    cycle: int
    wire_bytes: int


@dataclass(slots=True)
class UartSendStats:
    frames: int = 0
    wire_bytes: int = 0
    escapes: int = 0
    refused_strobes: int = 0
    writes_while_busy: int = 0
    filtered: int = 0  #: frames a fault hook lost on the wire


def frame_bytes(content: bytes, framing: Framing) -> bytes:
    """START + content with SKIP before every special + STOP (the module's byte order)."""
    return _escaper(framing).frame(content)


class _Escaper:
    """START, the content with SKIP before every special byte, STOP: SKIP itself doubled
    first, then START and STOP each preceded by SKIP (three replacements, no regular
    expression; SKIP differs from both, so none escapes another's)."""

    __slots__ = ("_head", "_skip", "_skip_skip", "_skip_start", "_skip_stop", "_tail",
                 "framing")

    def __init__(self, framing: Framing) -> None:
        self.framing = framing
        self._skip = bytes((framing.skip,))
        self._head = bytes((framing.start,))
        self._tail = bytes((framing.stop,))
        self._skip_skip = self._skip + self._skip
        self._skip_start = self._skip + self._head
        self._skip_stop = self._skip + self._tail

    def frame(self, content: bytes) -> bytes:
        escaped = content.replace(self._skip, self._skip_skip).replace(
            self._head, self._skip_start).replace(self._tail, self._skip_stop)
        return self._head + escaped + self._tail


#: One escaper per framing, made on first use.
_ESCAPERS: dict[Framing, _Escaper] = {}


def _escaper(framing: Framing) -> _Escaper:
    escaper = _ESCAPERS.get(framing)
    if escaper is None:
        escaper = _ESCAPERS[framing] = _Escaper(framing)
    return escaper


class UartSend:
    """Registers: ``length`` (content bytes in the TX RAM), the send strobe (:meth:`strobe`),
    ``busy``; the framing bytes (:meth:`set_framing`)."""

    def __init__(
        self,
        timeline: Timeline,
        bram: BlockRam,
        uartwrite: UartWrite,
        framing: Framing = DEFAULT_FRAMING,
    ) -> None:
        self._timeline = timeline
        self.bram = bram
        self.uartwrite = uartwrite
        self._escaper = _escaper(framing)
        self.length = 0
        self.stats = UartSendStats()
        #: cycle the current frame's last stop bit ends; idle from then on
        self.busy_until = 0
        self.frame_wire_bytes = 0  #: wire bytes of the frame being (or last) sent
        #: Fault hook: called with (content, cycle) at each accepted strobe; returning False
        #: loses the frame on the wire (it still takes its line time).
        self.frame_filter: FrameFilter | None = None
        self._done_listeners: list[Callable[[TxDone], None]] = []
        #: ``listener(content, cycle)`` at each accepted strobe (:meth:`on_frame`)
        self._frame_listeners: list[Callable[[bytes, int], None]] = []
        #: (end cycle, wire bytes) of each frame a done event is scheduled for, in order: a
        #: frame nobody listens for gets none
        self._ends: deque[tuple[int, int]] = deque()
        #: one-shot listeners, by the end cycle of the frame they wait for
        self._done_once: list[tuple[int, Callable[[TxDone], None]]] = []

    @property
    def busy(self) -> bool:
        # Computed from the cycle, not a flag cleared by an event, so every event of the
        # completion cycle sees the module idle whatever their order.
        return self._timeline.now < self.busy_until

    @property
    def framing(self) -> Framing:
        return self._escaper.framing

    def set_framing(self, framing: Framing) -> None:
        self._escaper = _escaper(framing)

    def set_length(self, length: int) -> None:
        if not 0 <= length <= self.bram.size:
            raise ValueError(f"TX length {length} does not fit the {self.bram.size}-byte RAM")
        self.length = length

    def on_frame(self, listener: Callable[[bytes, int], None]) -> None:
        """``listener(content, cycle)`` at every accepted strobe from now on, with the
        frame's content as the TX RAM holds it (before framing and any fault on the line):
        a logic analyser on the RAM, what a test checks the host received against."""
        self._frame_listeners.append(listener)

    def on_done(self, listener: Callable[[TxDone], None]) -> None:
        """``listener`` runs at the end of every frame from now on (the frame on the wire
        included)."""
        self._done_listeners.append(listener)
        self._ensure_finish()

    def on_next_done(self, listener: Callable[[TxDone], None]) -> None:
        """``listener`` runs once, at the end of the frame on the wire (the done interrupt
        enabled for one frame): software that has something waiting asks for it, so a frame
        nobody waits for costs no event at its end. Idle, nothing is on the wire and
        ``listener`` is not called."""
        if self.busy:
            self._done_once.append((self.busy_until, listener))
            self._ensure_finish()

    def _ensure_finish(self) -> None:
        """A done event at the end of the frame on the wire, if it has none yet."""
        end = self.busy_until
        if self.busy and not (self._ends and self._ends[-1][0] == end):
            self._ends.append((end, self.frame_wire_bytes))
            self._timeline.schedule(end, self._finish)

    def note_ram_write(self) -> None:
        """The processor wrote the TX RAM (called by the AXI side)."""
        if self._timeline.now < self.busy_until:  # busy, without the property's call
            self.stats.writes_while_busy += 1

    def strobe(self) -> bool:
        """Pulse the send strobe; returns whether the module accepted it."""
        if self._timeline.now < self.busy_until:  # busy, without the property's call
            self.stats.refused_strobes += 1
            return False
        return self._start_frame(self.bram.read_bytes(0, self.length))

    def load_and_strobe(self, content: bytes) -> bool:
        """The TX RAM written with ``content`` from address 0, the length register set to
        its size and the strobe pulsed, in one cycle: exactly :meth:`note_ram_write`, the
        RAM write, :meth:`set_length`, then :meth:`strobe`. Idle (the usual case), the
        frame goes out from ``content`` itself, which is what the RAM now holds."""
        if self._timeline.now < self.busy_until:
            self.note_ram_write()
            self.bram.write_bytes(0, content)
            self.set_length(len(content))
            return self.strobe()
        # Raises IndexError before anything changes when content does not fit the RAM, so
        # the length it sets below always fits.
        self.bram.write_bytes(0, content)
        self.length = len(content)
        return self._start_frame(content)

    def _start_frame(self, content: bytes) -> bool:
        """The accepted strobe: ``content`` (the RAM's first ``length`` bytes) goes out."""
        for frame_listener in self._frame_listeners:
            frame_listener(content, self._timeline.now)
        wire = self._escaper.frame(content)
        wire_bytes = len(wire)
        stats = self.stats
        stats.frames += 1
        stats.wire_bytes += wire_bytes
        stats.escapes += wire_bytes - len(content) - 2
        frame_filter = self.frame_filter
        lost = frame_filter is not None and not frame_filter(content, self._timeline.now)
        if lost:
            stats.filtered += 1
        self.busy_until = self.uartwrite.transmit(wire, lost=lost)
        # One frame at a time (a strobe while busy is refused), so its size can wait here.
        self.frame_wire_bytes = wire_bytes
        if self._done_listeners:
            self._ensure_finish()
        return True

    def _finish(self, cycle: int) -> None:
        # The frame's own size: the next frame may already have been strobed in this cycle.
        _, wire_bytes = self._ends.popleft()
        event = TxDone(cycle, wire_bytes)
        for listener in self._done_listeners:
            listener(event)
        if self._done_once:
            due = [listener for end, listener in self._done_once if end == cycle]
            self._done_once = [entry for entry in self._done_once if entry[0] != cycle]
            for listener in due:
                listener(event)
