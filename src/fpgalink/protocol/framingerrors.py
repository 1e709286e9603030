"""The counted framing errors a decoder reports (SPEC §3, docs/protocol.md §7): noise outside
any frame, frames aborted by a restart or an overflow, and frames the wire CRC refused.

Events, in a module of their own: the decoder (:mod:`.framing`) and the CRC's rules
(:mod:`.crc`) are compiled in the compiled build and these are not, because a compiled
class cannot derive from :class:`~fpgalink.protocol.event.Event`'s frozen dataclasses (they
are one class in both builds).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from fpgalink.protocol.event import Event

__all__ = ["AbortReason", "CrcMismatch", "FrameAborted", "FramingError", "NoiseDropped"]


@dataclass(frozen=True, slots=True)
class FramingError(Event):
    """Base of the counted framing errors; ``dropped`` is how many wire bytes were discarded."""

    dropped: int


@dataclass(frozen=True, slots=True)
class NoiseDropped(FramingError):
    """Bytes outside any frame (the decoder was hunting for START)."""


class AbortReason(Enum):
    RESTART = "restart"  #: an unescaped START arrived inside a frame
    OVERFLOW = "overflow"  #: content passed the limit


@dataclass(frozen=True, slots=True)
class FrameAborted(FramingError):
    """Frames that were started and never delivered: ``count`` of them in a row (a run of
    restarts is one event), ``dropped`` wire bytes in all."""

    reason: AbortReason
    count: int = 1


@dataclass(frozen=True, slots=True)
class CrcMismatch(FramingError):
    """A frame whose CRC did not match, dropped (``dropped``: its content bytes)."""

    content: bytes = b""
