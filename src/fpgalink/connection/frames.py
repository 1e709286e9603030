"""The framing layer of one link: bytes ↔ frame contents, with the optional wire CRC between
the frames and the messages (docs/protocol.md §7).

Received bytes go through the decoder and then, while the CRC is on (or its handshake is
out), through the check: a good CRC is stripped, a bad one makes the frame a
:class:`~fpgalink.protocol.CrcMismatch` (counted in ``crc_failures``), never a message.
Messages sent are encoded, given the CRC while it is on, and framed. The mode follows the
board's answer about ``WireCrc`` (:class:`~fpgalink.protocol.crc.HostWireCrc`).

A frame of the other mode is recognised and said (:class:`~fpgalink.events.WireCrcMismatch`,
once until the mode is settled again; ``crc_mode_mismatches``): with the CRC off, a counted
message with a good CRC after it that is none without it stripped; with the CRC on, a frame
failing the check that is a counted message as it is.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

from fpgalink.connection.stats import LinkStats
from fpgalink.events import WireCrcMismatch
from fpgalink.protocol import (
    TELEMETRY_RUN_MIN,
    CountedMessage,
    DirectCommand,
    Event,
    FrameDecoder,
    FrameEncoder,
    Framing,
    FramingError,
    Message,
    MessageId,
    SendCounter,
    content_length,
    encode_message,
)
from fpgalink.protocol.crc import (
    WIRE_CRC_PARAM,
    CrcMismatch,
    HostWireCrc,
    carries_crc,
    plain_counted,
)

__all__ = ["FrameLayer", "telemetry_runs"]

#: A TM frame's content bytes: runs of frames this size may be telemetry.
_TM_SIZE = content_length(MessageId.TM)


def telemetry_runs(items: list[bytes | FramingError]) -> Iterator[tuple[bool, list[Any]]]:
    """``items`` in stream order as (maybe telemetry?, items): runs of at least
    ``TELEMETRY_RUN_MIN`` TM-sized frames, which may go a run at a time, and the rest."""
    odd = [i for i, item in enumerate(items) if type(item) is not bytes or len(item) != _TM_SIZE]
    done = 0  # items before this one are handed out
    previous = -1  # the odd item before the run being looked at
    for i in (*odd, len(items)):
        if i - previous - 1 >= TELEMETRY_RUN_MIN:
            if previous + 1 > done:
                yield False, items[done : previous + 1]
            yield True, items[previous + 1 : i]
            done = i
        previous = i
    if done < len(items):
        yield False, items[done:]


class FrameLayer:
    """The decoder, the encoder (with this side's message counter) and the wire CRC of one
    link."""

    __slots__ = ("_counter", "_decoder", "_emit", "_encoder", "_stats", "framing", "mismatch",
                 "wire_crc")

    def __init__(self, framing: Framing, stats: LinkStats, emit: Callable[[Event], None],
                 crc_on: bool = False) -> None:
        self.framing = framing
        self.wire_crc = HostWireCrc()  #: as the board's answer about WireCrc says
        self.wire_crc.on = crc_on
        #: the board's frames came in the other mode: with the CRC (True) or without (False)
        self.mismatch: bool | None = None
        self._decoder = FrameDecoder(framing)
        self._encoder = FrameEncoder(framing)
        self._counter = SendCounter()
        self._stats = stats
        self._emit = emit

    @property
    def next_counter(self) -> int:
        """The counter value the next counted message will carry."""
        return self._counter.value

    def feed(self, data: bytes | bytearray | memoryview, now: float
             ) -> tuple[list[bytes | FramingError], bool]:
        """The items ``data`` completes (frame contents and framing errors, in order), and
        whether every one is a frame."""
        decoder = self._decoder
        before = decoder.stats.frames
        items = decoder.feed(data)
        if self.wire_crc.checking and items:
            items, failed = self.wire_crc.filter(items)
            if failed:
                self._stats.crc_failures += failed
                before += failed  # those items are CrcMismatch events now, not frames
                for item in items:
                    if type(item) is CrcMismatch and plain_counted(item.content):
                        self._other_mode(False, now)
        return items, decoder.stats.frames - before == len(items)

    def unexpected(self, content: bytes, now: float) -> bool:
        """Whether ``content``, no message, is one carrying the CRC while this host's is off
        (then counted and said here)."""
        if self.wire_crc.checking or not carries_crc(content):
            return False
        self._other_mode(True, now)
        return True

    def _other_mode(self, board_crc: bool, now: float) -> None:
        self._stats.crc_mode_mismatches += 1
        if self.mismatch is None:
            self.mismatch = board_crc
            self._emit(WireCrcMismatch(board_crc, at=now))

    def encode(self, message: Message | CountedMessage | DirectCommand) -> bytes:
        """``message``'s wire bytes (counted as sent): a counted one takes the next counter
        value (and carries the CRC while on), a direct command neither."""
        if isinstance(message, DirectCommand):
            content = message.content
        else:
            self.wire_crc.sent(message)
            content = self.wire_crc.outgoing(encode_message(message, self._counter.take()))
        wire = self._encoder.encode(content)
        self._stats.frames_sent += 1
        self._stats.bytes_sent += len(wire)
        return wire

    def answered(self, param_id: int, value: int | float | None) -> None:
        """A ``PA`` (``value``) or ``PN`` (``None``) about ``param_id`` arrived: the board's
        answer about ``WireCrc`` sets the mode."""
        if param_id == WIRE_CRC_PARAM:
            self.mismatch = None
        self.wire_crc.answered(param_id, value)

    def board_restarted(self) -> None:
        """A board powers up on the plain wire."""
        self.wire_crc.on = self.wire_crc.asking = False
        self.mismatch = None

    def reset(self) -> None:
        """A new port: a frame begun on the old one is gone."""
        self._decoder.reset()
