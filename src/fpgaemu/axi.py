"""What the MicroBlaze sees of the UART logic over AXI: interrupts, registers and the two
block RAMs. The firmware (part 2) is written against this class only.

Reads go through ``uartcommand.sync()`` first, so the processor sees exactly what the logic
holds at the current cycle even though received bytes are processed lazily.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from fpgaemu.bram import BlockRam
from fpgaemu.timeline import Timeline
from fpgaemu.uartcommand import EnableChange, RxInterrupt, UartCommand
from fpgaemu.uartsend import TxDone, UartSend
from fpgalink.protocol import Framing

__all__ = ["AxiBus", "TxQueue", "TxQueueStats"]


class AxiBus:
    """The processor's port: ``on_rx_interrupt``, ``read_rx``/``ack_rx``, ``write_tx`` +
    ``strobe_tx``, ``tx_busy``, ``on_tx_done``, ``global_enable``, ``set_framing``."""

    def __init__(
        self,
        timeline: Timeline,
        uartcommand: UartCommand,
        uartsend: UartSend,
        rx_bram: BlockRam,
        tx_bram: BlockRam,
    ) -> None:
        self._timeline = timeline
        self.uartcommand = uartcommand
        self.uartsend = uartsend
        self.rx_bram = rx_bram
        self.tx_bram = tx_bram

    @property
    def now(self) -> int:
        return self._timeline.now

    def set_framing(self, framing: Framing) -> None:
        """Start-up: program the framing bytes into both modules."""
        self.uartcommand.set_framing(framing)
        self.uartsend.set_framing(framing)

    # --- receive --------------------------------------------------------------------------

    def on_rx_interrupt(self, handler: Callable[[RxInterrupt], None]) -> None:
        """``handler`` runs in the cycle a message frame's STOP completes."""
        self.uartcommand.on_interrupt(handler)

    @property
    def rx_start_address(self) -> int:
        self.uartcommand.sync()
        return self.uartcommand.start_address

    @property
    def rx_length(self) -> int:
        self.uartcommand.sync()
        return self.uartcommand.length

    def read_rx_word(self, index: int) -> int:
        self.uartcommand.sync()
        return self.rx_bram.read_word(index)

    def read_rx(self, start_address: int, length: int) -> bytes:
        """The content bytes of a frame, as the firmware gets them from word reads."""
        self.uartcommand.sync()
        return self.rx_bram.read_bytes(start_address, length)

    def read_rx_frame(self) -> bytes:
        """The frame the registers describe now (the last delivered)."""
        cmd = self.uartcommand
        cmd.sync()
        return self.rx_bram.read_bytes(cmd.start_address, cmd.length)

    def take_rx(self, start_address: int, length: int) -> bytes:
        """:meth:`read_rx` then :meth:`ack_rx` of the same frame in the same cycle: what an
        interrupt handler does with each frame, one look at the logic instead of two."""
        cmd = self.uartcommand
        cmd.sync()
        content = self.rx_bram.read_bytes(start_address, length)
        cmd.ack_synced(start_address)
        return content

    def ack_rx(self, start_address: int | None = None) -> None:
        """Write the read-done register for the frame at ``start_address`` (default: the one
        the registers describe)."""
        cmd = self.uartcommand
        cmd.ack(cmd.start_address if start_address is None else start_address)

    # --- transmit -------------------------------------------------------------------------

    @property
    def tx_busy(self) -> bool:
        return self.uartsend.busy

    def write_tx_word(self, index: int, value: int) -> None:
        self.uartsend.note_ram_write()
        self.tx_bram.write_word(index, value)

    def write_tx(self, content: bytes | bytearray | memoryview) -> None:
        """Store ``content`` in the TX RAM (word writes, little-endian) and set the length
        register."""
        self.uartsend.note_ram_write()
        self.tx_bram.write_bytes(0, content)
        self.uartsend.set_length(len(content))

    def send_tx(self, content: bytes) -> bool:
        """:meth:`write_tx` then :meth:`strobe_tx` in the same cycle: what the firmware does
        with each message, one look at the logic instead of several. ``False`` if
        ``uartsend`` was busy and ignored the strobe (the RAM is written all the same)."""
        return self.uartsend.load_and_strobe(content)

    def strobe_tx(self) -> bool:
        """Pulse the send strobe; ``False`` if ``uartsend`` was busy and ignored it."""
        return self.uartsend.strobe()

    def on_tx_done(self, handler: Callable[[TxDone], None]) -> None:
        """``handler`` at the end of every frame."""
        self.uartsend.on_done(handler)

    def on_next_tx_done(self, handler: Callable[[TxDone], None]) -> None:
        """``handler`` once, at the end of the frame on the wire (nothing when idle)."""
        self.uartsend.on_next_done(handler)

    # --- enable ---------------------------------------------------------------------------

    @property
    def global_enable(self) -> bool:
        self.uartcommand.sync()
        return self.uartcommand.global_enable

    def on_global_enable(self, handler: Callable[[EnableChange], None]) -> None:
        self.uartcommand.on_enable_change(handler)


@dataclass(slots=True)
class TxQueueStats:
    queued: int = 0
    sent: int = 0
    dropped: int = 0  #: messages refused because the queue was full
    max_depth: int = 0


class TxQueue:
    """Firmware-side send queue: ``send(content)`` writes and strobes at once when
    ``uartsend`` is idle, otherwise keeps the message (bounded) and sends it from the TX-done
    interrupt — what the MicroBlaze software does around a module that ignores busy strobes.
    It asks for that interrupt only while it holds a message, so a frame sent straight away
    costs no event at its end. ``on_start(tag, done_cycle, wire_bytes)`` is told when each
    message goes on the wire, with the ``tag`` it was sent with (the caller's number)."""

    def __init__(
        self, axi: AxiBus, depth: int = 8,
        on_start: Callable[[int | None, int, int], None] | None = None,
    ) -> None:
        self._axi = axi
        self.depth = depth
        self._queue: deque[tuple[bytes, int | None]] = deque()
        self.stats = TxQueueStats()
        self._on_start = on_start
        self._waiting = False  #: the done interrupt is asked for

    def __len__(self) -> int:
        return len(self._queue)

    def send(self, content: bytes, tag: int | None = None) -> bool:
        """Send or queue ``content``; ``False`` if the queue was full and it was dropped."""
        if not self._queue and not self._axi.tx_busy:
            self._start(content, tag)
            return True
        if len(self._queue) >= self.depth:
            self.stats.dropped += 1
            return False
        self._queue.append((content, tag))
        self.stats.queued += 1
        self.stats.max_depth = max(self.stats.max_depth, len(self._queue))
        self._wait()
        return True

    def _wait(self) -> None:
        if not self._waiting:
            self._waiting = True
            self._axi.on_next_tx_done(self._on_done)

    def _start(self, content: bytes, tag: int | None) -> None:
        axi = self._axi
        accepted = axi.send_tx(content)
        assert accepted, "uartsend refused a strobe while idle"
        self.stats.sent += 1
        if self._on_start is not None:
            uartsend = axi.uartsend
            self._on_start(tag, uartsend.busy_until, uartsend.frame_wire_bytes)

    def _on_done(self, event: TxDone) -> None:
        self._waiting = False
        if self._queue and not self._axi.tx_busy:
            self._start(*self._queue.popleft())
        if self._queue:
            self._wait()
