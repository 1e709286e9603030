"""SPEC §3 framing: the ``uartsend`` encoder and the ``uartcommand`` streaming decoder.

The decoder has exactly the hardware's byte-by-byte semantics, checked against a naive
byte-at-a-time reference under hypothesis and a fuzzer, but it never walks the stream one
byte at a time in Python, and its cost is linear in its input for every input:

* **The clean stream** (frames back to back, the 1 kHz telemetry case) is split by one
  tokenizing regular expression that matches at *every* position — a frame (START, runs of
  ordinary bytes and SKIP-escaped pairs, then STOP if there is one) or a run of noise — so
  the regex engine never fails and retries from the next byte, which is what made a search
  for frames quadratic on runs of escaped STARTs. Whether every token is a complete frame
  is checked on the transposed token tuples with C-level calls.
* **Anything else** (noise, frames restarted by a START, overflows, the unfinished tail)
  goes through a loop over positions whose every step is one bounded C call: a run of
  clean frames within a window, a run of restarted frames of at most the content limit
  each, one overflowing frame, or a run of noise. Each step consumes what it scanned, or
  scans at most a window to consume at least a frame's worth, so adversarial input costs a
  constant factor of clean input, not its square.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import Enum

from fpgalink.protocol.errors import LocalProtocolError
from fpgalink.protocol.event import Event

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


#: The irregular path looks for a run of clean frames at most this far ahead, so a frame that
#: never ends costs one window of scanning, not the rest of the stream. Any size above the
#: longest frame that can complete (START, 2 × content limit, STOP) is exact.
_CLEAN_WINDOW = 1024
#: The clean-stream path tokenizes this many bytes at a time.
_TOKEN_WINDOW = 16384


class FrameDecoder:
    """Streaming SPEC §3 decoder. ``feed(data)`` returns, in stream order, each delivered
    frame's content (``bytes``) and each error (a :class:`FramingError`). It never raises on
    input, costs time linear in the input, and any chunking of the same stream gives the
    same frames and the same counts."""

    __slots__ = (
        "_clean_run",
        "_double_skip",
        "_frames_in",
        "_framing",
        "_markers",
        "_overflow",
        "_pairs",
        "_pending",
        "_restarts",
        "_skip_b",
        "_start_b",
        "_stop_b",
        "_tokens",
        "_window",
        "stats",
    )

    def __init__(self, framing: Framing = DEFAULT_FRAMING) -> None:
        self._framing = framing
        s, p, k = (re.escape(bytes((b,))) for b in framing.specials)
        ordinary = b"[^" + s + p + k + b"]"
        # The unrolled form keeps the common run of ordinary bytes in one possessive repeat.
        body = ordinary + b"*+(?:" + k + b"." + ordinary + b"*+)*+"
        unit = b"(?:" + ordinary + b"|" + k + b".)"
        limit = str(framing.max_content).encode()
        flags = re.DOTALL
        # A token at every position: (body, how it ends, noise run). A frame ends in STOP, in
        # a SKIP that is the buffer's last byte (an escape cut by the read), or in nothing (a
        # START follows, or the buffer ends).
        self._tokens = re.compile(
            s + b"(" + body + b")(" + p + b"|" + k + rb"\Z|)|([^" + s + b"]++)", flags
        ).findall
        self._clean_run = re.compile(b"(?:" + s + body + p + b")++", flags).match
        self._frames_in = re.compile(s + b"(" + body + b")" + p, flags).findall
        self._restarts = re.compile(
            b"(?:" + s + unit + b"{0," + limit + b"}+(?=" + s + b"))++", flags
        ).match
        self._overflow = re.compile(s + unit + b"{" + limit + b"}+" + unit, flags).match
        self._pairs = re.compile(k + b".", flags).sub
        self._window = max(_CLEAN_WINDOW, 2 * framing.max_content + 3)
        self._start_b = bytes((framing.start,))
        self._stop_b = bytes((framing.stop,))
        self._skip_b = bytes((framing.skip,))
        self._double_skip = self._skip_b * 2
        # Candidates to stand in for an escaped SKIP while unescaping; rare bytes first.
        self._markers = tuple(
            bytes((b,)) for b in (0xFE, 0xFD, 0x01, 0xFB, *range(256)) if b != framing.skip
        )
        #: wire bytes of an unfinished frame, from its START; empty while hunting
        self._pending = b""
        self.stats = FramingStats()

    @property
    def framing(self) -> Framing:
        return self._framing

    @property
    def pending(self) -> int:
        """Wire bytes held for a frame not yet finished (at most ``2 × max_content + 2``)."""
        return len(self._pending)

    def reset(self) -> None:
        """Forget any unfinished frame (counted as dropped), as the hardware does on reset."""
        if self._pending:
            self.stats.dropped_bytes += len(self._pending)
            self._pending = b""

    def feed(self, data: bytes | bytearray | memoryview) -> list[bytes | FramingError]:
        stats = self.stats
        stats.bytes_fed += len(data)
        buf = self._pending + bytes(data) if self._pending else bytes(data)
        self._pending = b""
        out: list[bytes | FramingError] = []
        limit = self._framing.max_content
        stop = self._stop_b
        n = len(buf)
        pos = 0
        # Token lists are built a bounded window at a time, so a read of any size costs the
        # same per byte.
        while pos < n:
            end = min(n, pos + _TOKEN_WINDOW)
            tokens = self._tokens(buf, pos, end)
            bodies, ends, noise = zip(*tokens, strict=True)
            complete = ends.count(stop) == len(ends)
            if not (noise.count(b"") == len(noise) and (
                complete
                or (ends.count(stop) == len(ends) - 1 and ends[-1] != stop
                    and len(bodies[-1]) <= limit)
            )):
                self._irregular(buf, pos, out)
                return out
            # Frames back to back, perhaps an unfinished one last that cannot have passed
            # the limit yet: the 1 kHz case.
            if not complete:
                bodies = bodies[:-1]
            contents = self._unescape_all(bodies)
            if contents and max(map(len, contents)) > limit:
                self._irregular(buf, pos, out)
                return out
            plain = sum(map(len, contents))
            wire = sum(map(len, bodies)) + 2 * len(bodies)
            stats.frames += len(contents)
            stats.frame_bytes += plain + 2 * len(contents)
            stats.escape_bytes += wire - 2 * len(contents) - plain
            out += contents
            pos += wire
            if not complete and end == n:
                self._pending = buf[pos:]
                break
        return out

    def _unescape_all(self, bodies: tuple[bytes, ...]) -> list[bytes]:
        skip, double = self._skip_b, self._double_skip
        return [
            b if skip not in b else b.replace(skip, b"") if double not in b else self._unescape(b)
            for b in bodies
        ]

    def _unescape(self, content: bytes) -> bytes:
        """Content with an escaped SKIP: scanning from the left, a doubled SKIP always starts
        on an escape pair. Park each escaped SKIP as SKIP + a byte the content lacks, drop
        every SKIP (all prefixes now), then turn the parked bytes back into SKIPs."""
        skip_b, double = self._skip_b, self._double_skip
        for marker in self._markers:
            if marker not in content:
                return content.replace(double, skip_b + marker).replace(skip_b, b"").replace(
                    marker, skip_b
                )
        # Content using every byte value (only possible with a limit over 255).
        return skip_b.join([piece.replace(skip_b, b"") for piece in content.split(double)])

    def _irregular(self, buf: bytes, pos: int, out: list[bytes | FramingError]) -> None:
        """The exact state machine from ``pos`` over a stream with noise, restarts and
        overflows, one bounded C call per step."""
        stats = self.stats
        n = len(buf)
        start_b = self._start_b
        limit = self._framing.max_content
        window = self._window
        while pos < n:
            if buf[pos] != start_b[0]:
                end = buf.find(start_b, pos)
                if end < 0:
                    end = n
                stats.noise_runs += 1
                stats.noise_bytes += end - pos
                stats.dropped_bytes += end - pos
                out.append(NoiseDropped(end - pos))
                pos = end
                continue
            m = self._clean_run(buf, pos, pos + window)
            if m is not None:
                end = m.end()
                bodies = self._frames_in(buf, pos, end)
                contents = self._unescape_all(tuple(bodies))
                good = len(contents)
                if max(map(len, contents)) > limit:
                    good = next(i for i, c in enumerate(contents) if len(c) > limit)
                    end = pos + sum(map(len, bodies[:good])) + 2 * good
                if good:
                    plain = sum(map(len, contents[:good]))
                    stats.frames += good
                    stats.frame_bytes += plain + 2 * good
                    stats.escape_bytes += end - pos - 2 * good - plain
                    out += contents[:good]
                    pos = end
                    continue
            m = self._restarts(buf, pos)
            if m is not None:
                end = m.end()
                # Every unescaped START in the run opened a frame the next one aborted.
                count = self._pairs(b"", buf[pos:end]).count(start_b)
                stats.restarts += count
                stats.dropped_bytes += end - pos
                out.append(FrameAborted(end - pos, AbortReason.RESTART, count))
                pos = end
                continue
            m = self._overflow(buf, pos)
            if m is not None:
                # Dropped at the (limit + 1)th content byte; hunting resumes after it.
                end = m.end()
                stats.overflows += 1
                stats.dropped_bytes += end - pos
                out.append(FrameAborted(end - pos, AbortReason.OVERFLOW))
                pos = end
                continue
            # A frame of at most the limit that the buffer ends in (perhaps mid-escape).
            self._pending = buf[pos:]
            return
