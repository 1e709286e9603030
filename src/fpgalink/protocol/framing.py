"""SPEC §3 framing: the ``uartsend`` encoder and the ``uartcommand`` streaming decoder.

The decoder has exactly the hardware's byte-by-byte semantics, checked against a naive
byte-at-a-time reference under hypothesis and a fuzzer, but it never walks the stream one
byte at a time in Python, and its cost is linear in its input for every input:

* **The clean stream** (frames back to back, the 1 kHz telemetry case) costs a handful of
  C calls per read, none per byte or per frame in Python: one possessive regular
  expression finds where the run of whole frames ends (it never backtracks, and it is tried
  once per read, so a read it scans in vain costs one pass); within such a run STOP + START
  occurs only between frames, so one ``split`` cuts out every frame's wire body; bodies
  without a SKIP are already their content (a byte-membership test, no buffer protocol),
  the others are unescaped by ``replace`` and ``translate``; the counts come from lengths.
  An unfinished frame the read ends in is checked by one more match and kept.
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

from fpgalink.protocol.errors import LocalProtocolError
from fpgalink.protocol.framingerrors import AbortReason, FrameAborted, FramingError, NoiseDropped

__all__ = [
    "DEFAULT_FRAMING",
    "AbortReason",
    "FrameAborted",
    "FrameDecoder",
    "FrameEncoder",
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


class FrameEncoder:
    """``uartsend``'s framing for one :class:`Framing`: what :func:`encode_frame` does, with
    the framing's bytes looked up once (a link keeps one for its frames)."""

    __slots__ = ("_escapes", "_head", "_max_content", "_tail", "framing")

    def __init__(self, framing: Framing = DEFAULT_FRAMING) -> None:
        self.framing = framing
        self._max_content = framing.max_content
        self._head = bytes((framing.start,))
        self._tail = bytes((framing.stop,))
        skip = bytes((framing.skip,))
        # SKIP first, so the SKIPs put before START and STOP are not doubled again.
        self._escapes = tuple(
            (bytes((b,)), skip + bytes((b,))) for b in (framing.skip, framing.start, framing.stop)
        )

    def encode(self, content: bytes | bytearray | memoryview) -> bytes:
        """Wrap ``content`` in START/STOP, putting SKIP before every special byte;
        :class:`FrameTooLong` for content the receiver would drop as an overflow."""
        if len(content) > self._max_content:
            raise FrameTooLong(
                f"frame content is {len(content)} bytes; the receiver drops anything over "
                f"{self._max_content}"
            )
        (k, kk), (s, ks), (p, kp) = self._escapes
        body = content if type(content) is bytes else bytes(content)
        return self._head + body.replace(k, kk).replace(s, ks).replace(p, kp) + self._tail


_encoders: dict[Framing, FrameEncoder] = {}


def encode_frame(
    content: bytes | bytearray | memoryview, framing: Framing = DEFAULT_FRAMING
) -> bytes:
    """Wrap ``content`` in START/STOP, putting SKIP before every special byte (``uartsend``)."""
    encoder = _encoders.get(framing)
    if encoder is None:
        encoder = _encoders[framing] = FrameEncoder(framing)
    return encoder.encode(content)


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


_marker_cache: dict[int, tuple[tuple[int, bytes, bytes], ...]] = {}


def _markers(skip: int) -> tuple[tuple[int, bytes, bytes], ...]:
    """Candidates to stand in for an escaped SKIP while unescaping, rare bytes first: (the
    byte, as an int for a membership test that needs no buffer, SKIP + it, a table mapping
    it to SKIP). Shared by every decoder with this SKIP: the tables are 64 KiB in all."""
    markers = _marker_cache.get(skip)
    if markers is None:
        skip_b = bytes((skip,))
        markers = _marker_cache[skip] = tuple(
            (b, skip_b + bytes((b,)), bytes.maketrans(bytes((b,)), skip_b))
            for b in dict.fromkeys((0xFE, 0xFD, 0x01, 0xFB, *range(256))) if b != skip
        )
    return markers


class FrameDecoder:
    """Streaming SPEC §3 decoder. ``feed(data)`` returns, in stream order, each delivered
    frame's content (``bytes``) and each error (a :class:`FramingError`). It never raises on
    input, costs time linear in the input, and any chunking of the same stream gives the
    same frames and the same counts."""

    __slots__ = (
        "_boundary",
        "_clean_run",
        "_double_skip",
        "_framing",
        "_markers",
        "_overflow",
        "_pairs",
        "_partial",
        "_pending",
        "_restarts",
        "_skip",
        "_skip_b",
        "_start",
        "_start_b",
        "_window",
        "stats",
    )

    def __init__(self, framing: Framing = DEFAULT_FRAMING) -> None:
        self._framing = framing
        s, p, k = (re.escape(bytes((b,))) for b in framing.specials)
        # Listed rather than negated: the engine tests a plain byte class with one bitmap
        # lookup, a negated one measurably slower, and this class is tested on nearly every
        # byte of the stream.
        ordinary = b"[" + b"".join(
            re.escape(bytes((b,))) for b in range(256) if b not in framing.specials
        ) + b"]"
        # The unrolled form keeps the common run of ordinary bytes in one possessive repeat.
        body = ordinary + b"*+(?:" + k + b"." + ordinary + b"*+)*+"
        unit = b"(?:" + ordinary + b"|" + k + b".)"
        limit = str(framing.max_content).encode()
        flags = re.DOTALL
        # Every pattern is possessive throughout, so a match attempt never backtracks: its
        # cost is the bytes it scans, once.
        self._clean_run = re.compile(b"(?:" + s + body + p + b")++", flags).match
        # An unfinished frame the buffer ends in, perhaps cut inside an escape pair.
        self._partial = re.compile(s + body + k + b"?+", flags).fullmatch
        self._restarts = re.compile(
            b"(?:" + s + unit + b"{0," + limit + b"}+(?=" + s + b"))++", flags
        ).match
        self._overflow = re.compile(s + unit + b"{" + limit + b"}+" + unit, flags).match
        self._pairs = re.compile(k + b".", flags).sub
        self._window = max(_CLEAN_WINDOW, 2 * framing.max_content + 3)
        self._start = framing.start
        self._skip = framing.skip
        self._start_b = bytes((framing.start,))
        self._skip_b = bytes((framing.skip,))
        self._double_skip = self._skip_b * 2
        self._boundary = bytes((framing.stop, framing.start))
        self._markers = _markers(framing.skip)
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
        self.stats.bytes_fed += len(data)
        if self._pending:
            buf = self._pending + data
            self._pending = b""
        else:
            buf = bytes(data)
        out: list[bytes | FramingError] = []
        n = len(buf)
        pos = 0
        # The 1 kHz case: frames back to back from the first byte, perhaps an unfinished one
        # last. One possessive match finds where the run of whole frames ends; it is tried
        # once per read, so even a buffer it scans to the end in vain costs one pass.
        if n and buf[0] == self._start:
            m = self._clean_run(buf)
            if m is not None:
                pos = self._deliver(buf, 0, m.end(), out)
        if pos < n:
            if buf[pos] == self._start and self._partial(buf, pos) is not None and (
                n - pos - 1 <= self._framing.max_content
                or self._content_length(buf[pos + 1 :]) <= self._framing.max_content
            ):
                self._pending = buf[pos:]
            else:
                self._irregular(buf, pos, out)
        return out

    def _content_length(self, wire: bytes) -> int:
        """Content bytes so far of an unfinished frame's wire after its START: scanning from
        the left, a doubled SKIP is always one escaped SKIP; every SKIP left is an escape."""
        packed = wire.replace(self._double_skip, self._start_b)
        return len(packed) - packed.count(self._skip)

    def _deliver(self, buf: bytes, start: int, end: int, out: list[bytes | FramingError]
                 ) -> int:
        """Deliver the whole frames that ``buf[start:end]`` holds back to back (a match of
        ``_clean_run``), up to the first over the content limit; returns where delivery
        stopped.

        Between START and STOP an unescaped START or STOP never occurs, and an escaped one
        follows a SKIP, so within such a run STOP + START occurs only where a frame ends and
        the next begins: one split cuts the run into the frames' wire bodies."""
        stats = self.stats
        region = buf[start + 1 : end - 1]
        bodies = region.split(self._boundary)
        skip = self._skip
        if skip in region:
            # The first stand-in, tried inline: a body rarely holds it, and a call per
            # escaped body would cost more than the unescaping.
            unescape, skip_b, double = self._unescape, self._skip_b, self._double_skip
            marker, parked, back = self._markers[0]
            contents = [
                b if skip not in b
                else b.replace(double, parked).translate(back, skip_b) if marker not in b
                else unescape(b)
                for b in bodies
            ]
            plain = sum(map(len, contents))
        else:
            contents = bodies
            plain = end - start - 2 * len(bodies)
        limit = self._framing.max_content
        if max(map(len, contents)) > limit:
            good = next(i for i, c in enumerate(contents) if len(c) > limit)
            if not good:
                return start
            end = start + sum(map(len, bodies[:good])) + 2 * good
            contents = contents[:good]
            plain = sum(map(len, contents))
        frames = len(contents)
        stats.frames += frames
        stats.frame_bytes += plain + 2 * frames
        stats.escape_bytes += end - start - 2 * frames - plain
        out += contents
        return end

    def _unescape(self, body: bytes) -> bytes:
        """A wire body with escapes: scanning from the left, a doubled SKIP always starts on
        an escape pair. Park each escaped SKIP as SKIP + a byte the body lacks, drop every
        SKIP (all prefixes now), then turn the parked bytes back into SKIPs."""
        skip_b, double = self._skip_b, self._double_skip
        for marker, parked, back in self._markers:
            if marker not in body:
                # translate deletes before it maps: every SKIP goes, then the parked byte
                # becomes a SKIP.
                return body.replace(double, parked).translate(back, skip_b)
        # A body using every byte value (only possible with a limit over 255).
        return skip_b.join([piece.replace(skip_b, b"") for piece in body.split(double)])

    def _irregular(self, buf: bytes, pos: int, out: list[bytes | FramingError]) -> None:
        """The exact state machine from ``pos`` over a stream with noise, restarts and
        overflows, one bounded C call per step."""
        stats = self.stats
        n = len(buf)
        start_b = self._start_b
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
                end = self._deliver(buf, pos, m.end(), out)
                if end > pos:
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
