"""SPEC §3 framing: the ``uartsend`` encoder and the ``uartcommand`` streaming decoder.

The decoder has exactly the hardware's byte-by-byte semantics, but it does not walk the
stream one byte at a time in Python: a regular expression finds each well-formed frame
(a START, then runs of ordinary bytes and SKIP-escaped pairs, then an unescaped STOP) at C
speed, and only the bytes *between* frames (noise, aborted frames, overflows) and the
unfinished tail go through the exact byte-level state machine. The two agree because a
complete frame that the state machine would deliver is always the leftmost regex match;
the hypothesis tests check this against a naive reference decoder.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import Enum

from fpgalink.errors import LocalProtocolError

__all__ = [
    "DEFAULT_FRAMING",
    "AbortReason",
    "FrameAborted",
    "FrameDecoder",
    "FrameTooLong",
    "Framing",
    "FramingError",
    "FramingStats",
    "NoiseDropped",
    "encode_frame",
]

#: Content longer than this is garbage (SPEC §3); the RX block RAM holds two such halves.
DEFAULT_MAX_CONTENT = 200


class FrameTooLong(LocalProtocolError):
    """Raised by the encoder for content the receiving hardware would drop as an overflow."""


@dataclass(frozen=True, slots=True)
class Framing:
    """The three framing bytes and the content limit, as the processor configures them."""

    start: int = 0x53  #: ``S``
    stop: int = 0x50  #: ``P``
    skip: int = 0x5C  #: ``\``
    max_content: int = DEFAULT_MAX_CONTENT

    def __post_init__(self) -> None:
        for name in ("start", "stop", "skip"):
            value = getattr(self, name)
            if not isinstance(value, int) or not 0 <= value <= 255:
                raise ValueError(f"framing byte {name}={value!r} is not a byte value 0..255")
        if len({self.start, self.stop, self.skip}) != 3:
            raise ValueError(
                "framing bytes must be three distinct values, got "
                f"start={self.start:#04x} stop={self.stop:#04x} skip={self.skip:#04x}"
            )
        if not isinstance(self.max_content, int) or self.max_content < 1:
            raise ValueError(f"max_content must be a positive integer, got {self.max_content!r}")

    @property
    def specials(self) -> bytes:
        return bytes((self.start, self.stop, self.skip))


DEFAULT_FRAMING = Framing()


class _Encoder:
    __slots__ = ("_escapes", "_framing", "_head", "_tail")

    def __init__(self, framing: Framing) -> None:
        self._framing = framing
        self._head = bytes((framing.start,))
        self._tail = bytes((framing.stop,))
        skip = bytes((framing.skip,))
        # SKIP first, so the SKIPs put before START and STOP are not doubled again.
        self._escapes = tuple(
            (bytes((b,)), skip + bytes((b,))) for b in (framing.skip, framing.start, framing.stop)
        )

    def encode(self, content: bytes) -> bytes:
        if len(content) > self._framing.max_content:
            raise FrameTooLong(
                f"frame content is {len(content)} bytes; the receiver drops anything over "
                f"{self._framing.max_content}"
            )
        (k, kk), (s, ks), (p, kp) = self._escapes
        return self._head + content.replace(k, kk).replace(s, ks).replace(p, kp) + self._tail


_encoders: dict[Framing, _Encoder] = {}


def encode_frame(
    content: bytes | bytearray | memoryview, framing: Framing = DEFAULT_FRAMING
) -> bytes:
    """Wrap ``content`` in START/STOP, putting SKIP before every special byte (``uartsend``)."""
    encoder = _encoders.get(framing)
    if encoder is None:
        encoder = _encoders[framing] = _Encoder(framing)
    return encoder.encode(bytes(content))


# --- decoder events -------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class FramingError:
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
    """A frame that was started and never delivered."""

    reason: AbortReason


@dataclass(slots=True)
class FramingStats:
    """Running totals. Every byte fed is exactly one of: in a delivered frame (``frame_bytes``,
    START/STOP and content), an escape within a delivered frame (``escape_bytes``), dropped
    (``dropped_bytes``), or still ``pending`` in an unfinished frame."""

    frames: int = 0
    frame_bytes: int = 0
    escape_bytes: int = 0
    dropped_bytes: int = 0
    noise_runs: int = 0
    noise_bytes: int = 0
    restarts: int = 0
    overflows: int = 0
    bytes_fed: int = 0

    @property
    def errors(self) -> int:
        return self.restarts + self.overflows


_HUNT, _FRAME, _ESCAPE = 0, 1, 2


class FrameDecoder:
    """Streaming SPEC §3 decoder. ``feed(data)`` returns, in stream order, each delivered
    frame's content (``bytes``) and each error (a :class:`FramingError`). It never raises on
    input; any chunking of the same stream gives the same results."""

    __slots__ = (
        "_aborted_len",
        "_double_skip",
        "_frame_re",
        "_framing",
        "_markers",
        "_pending",
        "_skip_b",
        "stats",
    )

    def __init__(self, framing: Framing = DEFAULT_FRAMING) -> None:
        self._framing = framing
        s, p, k = (re.escape(bytes((b,))) for b in framing.specials)
        ordinary = b"[^" + s + p + k + b"]"
        # The "unrolled loop" form keeps the common run of ordinary bytes in one fast repeat.
        self._frame_re = re.compile(
            s + b"(" + ordinary + b"*+(?:" + k + b"." + ordinary + b"*+)*+)" + p, re.DOTALL
        )
        self._double_skip = bytes((framing.skip, framing.skip))
        # Candidates to stand in for an escaped SKIP while unescaping; rare bytes first.
        self._markers = tuple(
            bytes((b,)) for b in (0xFE, 0xFD, 0x01, 0xFB, *range(256)) if b != framing.skip
        )
        self._skip_b = bytes((framing.skip,))
        #: wire bytes of an unfinished frame, from its START; empty while hunting
        self._pending = b""
        self._aborted_len = 0
        self.stats = FramingStats()

    @property
    def framing(self) -> Framing:
        return self._framing

    @property
    def pending(self) -> int:
        """Wire bytes held for a frame not yet finished."""
        return len(self._pending)

    def reset(self) -> None:
        """Forget any unfinished frame (counted as dropped), as the hardware does on reset."""
        if self._pending:
            self.stats.dropped_bytes += len(self._pending)
            self._pending = b""

    def feed(self, data: bytes | bytearray | memoryview) -> list[bytes | FramingError]:
        data = bytes(data)
        stats = self.stats
        stats.bytes_fed += len(data)
        buf = self._pending + data if self._pending else data
        self._pending = b""
        # split() with one capturing group gives [gap, content, gap, content, ..., tail] in C.
        parts = self._frame_re.split(buf)
        if len(parts) > 1:
            contents = parts[1::2]
            tail = parts[-1]
            skip_b = self._skip_b
            unescaped: list[bytes] = []
            if not any(parts[0:-1:2]):
                unescaped = [c if skip_b not in c else self._unescape(c) for c in contents]
            if unescaped and max(map(len, unescaped)) <= self._framing.max_content:
                # Clean stream: frames back to back, none over the limit. The common case
                # costs a few C calls per frame.
                wire = sum(map(len, contents))
                plain = sum(map(len, unescaped))
                stats.frames += len(unescaped)
                stats.frame_bytes += plain + 2 * len(unescaped)
                out: list[bytes | FramingError] = unescaped  # type: ignore[assignment]
                stats.escape_bytes += wire - plain
                pos = len(buf) - len(tail)
            else:
                out = []
                pos = self._general(buf, out)
        else:
            out = []
            pos = 0
        n = len(buf)
        if pos < n:
            state = self._slow(buf, pos, n, out)
            if state != _HUNT:
                self._pending = buf[n - self._aborted_len :]
        return out

    def _unescape(self, content: bytes) -> bytes:
        skip_b = self._skip_b
        double = self._double_skip
        if double not in content:
            # No escaped SKIP, so every SKIP is an escape prefix and can simply go.
            return content.replace(skip_b, b"")
        # Scanning from the left, a doubled SKIP always starts on an escape pair. Park each
        # escaped SKIP as SKIP + a byte the content lacks, drop every SKIP (all prefixes
        # now), then turn the parked bytes back into SKIPs: three C calls per frame.
        for marker in self._markers:
            if marker not in content:
                return content.replace(double, skip_b + marker).replace(skip_b, b"").replace(
                    marker, skip_b
                )
        # Content using every byte value (only possible with a limit over 255).
        return skip_b.join([piece.replace(skip_b, b"") for piece in content.split(double)])

    def _general(self, buf: bytes, out: list[bytes | FramingError]) -> int:
        """Frames with noise, aborts or overflows between them; returns where the unmatched
        tail begins."""
        stats = self.stats
        pos = 0
        limit = self._framing.max_content
        skip_b = self._skip_b
        search = self._frame_re.search
        n = len(buf)
        while pos < n:
            m = search(buf, pos)
            if m is None:
                break
            start = m.start()
            if start != pos:
                # Nothing in a gap can be a complete frame (it would have been the leftmost
                # match), so the slow path only has errors to count here.
                state = self._slow(buf, pos, start, out)
                if state != _HUNT:
                    # The match's START interrupts a frame the gap opened.
                    stats.restarts += 1
                    dropped = self._aborted_len
                    stats.dropped_bytes += dropped
                    out.append(FrameAborted(dropped, AbortReason.RESTART))
            wire_content = m.group(1)
            content = self._unescape(wire_content) if skip_b in wire_content else wire_content
            if len(content) > limit:
                pos = self._overflow_at(buf, start, out)
                continue
            stats.frames += 1
            stats.frame_bytes += len(content) + 2
            stats.escape_bytes += len(wire_content) - len(content)
            out.append(content)
            pos = m.end()
        return pos

    # The byte-level state machine, used only off the fast path. It appends error events,
    # updates the counters, and leaves in ``_aborted_len`` the wire length of the frame it is
    # inside at ``stop`` (START included), so the caller can drop or keep it.
    def _slow(self, buf: bytes, pos: int, stop: int, out: list[bytes | FramingError]) -> int:
        f = self._framing
        start_byte, stop_byte, skip_byte, limit = f.start, f.stop, f.skip, f.max_content
        stats = self.stats
        state = _HUNT
        frame_wire = 0  # wire bytes of the current frame so far, START included
        content = bytearray()
        noise = 0
        for i in range(pos, stop):
            b = buf[i]
            if state == _HUNT:
                if b == start_byte:
                    if noise:
                        self._noise(noise, out)
                        noise = 0
                    state, frame_wire = _FRAME, 1
                    content.clear()
                else:
                    noise += 1
                continue
            frame_wire += 1
            if state == _ESCAPE:
                state = _FRAME
            elif b == skip_byte:
                state = _ESCAPE
                continue
            elif b == start_byte:
                stats.restarts += 1
                stats.dropped_bytes += frame_wire - 1
                out.append(FrameAborted(frame_wire - 1, AbortReason.RESTART))
                frame_wire = 1
                content.clear()
                continue
            elif b == stop_byte:
                # ``feed`` routes every complete frame through the fast path; this keeps the
                # machine exact on its own all the same.
                stats.frames += 1
                stats.frame_bytes += len(content) + 2
                stats.escape_bytes += frame_wire - len(content) - 2
                out.append(bytes(content))
                state = _HUNT
                continue
            content.append(b)
            if len(content) > limit:
                stats.overflows += 1
                stats.dropped_bytes += frame_wire
                out.append(FrameAborted(frame_wire, AbortReason.OVERFLOW))
                state = _HUNT
        if noise:
            self._noise(noise, out)
        self._aborted_len = frame_wire if state != _HUNT else 0
        return state

    def _noise(self, count: int, out: list[bytes | FramingError]) -> None:
        stats = self.stats
        stats.noise_runs += 1
        stats.noise_bytes += count
        stats.dropped_bytes += count
        out.append(NoiseDropped(count))

    def _overflow_at(self, buf: bytes, start: int, out: list[bytes | FramingError]) -> int:
        """A matched frame whose content passes the limit: drop it up to and including the
        first content byte over the limit, and return where hunting resumes."""
        f = self._framing
        limit, skip_byte = f.max_content, f.skip
        i = start + 1
        content_len = 0
        while True:
            if buf[i] == skip_byte:
                i += 1
            content_len += 1
            if content_len > limit:
                break
            i += 1
        dropped = i + 1 - start
        self.stats.overflows += 1
        self.stats.dropped_bytes += dropped
        out.append(FrameAborted(dropped, AbortReason.OVERFLOW))
        return i + 1
