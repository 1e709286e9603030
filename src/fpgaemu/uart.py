"""``uartread`` / ``uartwrite``: the 8N1 line in each direction, with optional fault injection.

A byte on the wire is 10 bit times: a low start bit, eight data bits LSB first, a high stop
bit; the receiver has the byte when the stop bit ends. At the default 1 MBd a bit is 100
cycles and a byte 1,000. A burst is handled as a whole: the line computes every byte's
completion cycle (a :class:`ByteRun`: data, first completion, spacing) and hands the run on
in one call, so a busy line costs one Python call per burst, not per byte or bit.

Bytes sent faster than line rate queue as on a real wire: each starts when the previous
one's stop bit has ended. A line idle when a burst arrives starts it at once.

Fault injection (:class:`LineFaults`, off by default) switches a burst to an exact bit-level
model: the burst is laid out as bit slots, chosen bits are flipped (by byte and bit index or
at a bit-error rate from the board's seeded generator), bytes can be lost, duplicated or
noise bytes inserted (by index or at a rate), and the line can be held low (a break) or cut
(held idle) for windows of time. The receiver (:class:`SlotReceiver`) is then a function of
the waveform alone, whatever bursts the sender cut it into: it is LiteX's ``RS232PHYRX`` in
slot terms (checked against that RTL in ``tests/fpgaemu/test_uart_hdl.py``). It starts a
byte on a falling edge (high → low), samples each bit once at LiteX's sample points, and
drops a byte whose stop bit reads low (a framing error, counted); it hunts for the next
falling edge from mid-stop, so a low stop bit directly followed by a start bit loses that
start too, and a break gives one framing error however long it lasts. A byte is delivered
at the end of its stop bit, 46 cycles after LiteX raises ``valid`` (at 1 MBd): a constant
offset. A byte whose samples run past the end of what has been sent is decided when the
next burst arrives or, if none does, when its stop bit ends (the line was idle).
Simplification: a break or cut acts only on bit slots sent during it (an idle line held low
produces nothing here, where a real receiver would see one falling edge).

Per board the receiver can instead be level-triggered (``rx_mode="level"``,
:class:`LevelReceiver`): a 16550's, verilog-uart's and OpenTitan's way, a start on any low
level with the start bit checked again at mid-bit (checked against OpenTitan's ``uart_rx``
RTL). The two modes agree on clean traffic and data faults and part after low stop bits,
breaks and lost start bits.

Rate-based faults are decided per burst before any bit is laid out, so a burst nothing hits
still takes the fast path: at a bit-error rate of 1e-4 about 95 % of 55-byte frames do. Each
kind of random fault draws from its own generator (``Timeline.rng(line + "." + kind)``), so
switching one fault on never changes where another one strikes.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final

from fpgaemu.timeline import CLOCK_HZ, Timeline
from fpgalink.protocol.faults import MAX_NOISE_LEN

if TYPE_CHECKING:  # numpy loads only for a line with faults
    import numpy as np

__all__ = [
    "BITS_PER_BYTE",
    "BIT_START",
    "BIT_STOP",
    "DEFAULT_BAUD",
    "LEVEL_SYNC_CYCLES",
    "UART_RX_MODES",
    "ByteRun",
    "LevelReceiver",
    "LineFaults",
    "LineStats",
    "SlotReceiver",
    "UartRead",
    "UartWrite",
    "cycles_per_bit",
    "litex_sample_points",
]

DEFAULT_BAUD: Final = 1_000_000
#: 8N1: start + 8 data + stop.
BITS_PER_BYTE: Final = 10
#: Bit indexes within a byte's 10 slots, for :class:`LineFaults` (data bit k is slot k + 1).
BIT_START: Final = 0
BIT_STOP: Final = 9


#: How a receiver finds a start bit: ``edge`` (LiteX's ``RS232PHYRX``: a falling edge,
#: :class:`SlotReceiver`) or ``level`` (a 16550's, verilog-uart's, OpenTitan's ``uart_rx``:
#: a low level, checked again at mid-bit, :class:`LevelReceiver`).
UART_RX_MODES = ("edge", "level")
#: The level receiver's input synchroniser (two flip-flops, as OpenTitan's ``uart_core``).
LEVEL_SYNC_CYCLES: Final = 2
#: The level receiver's sampling clock: this many ticks per bit (a 16550's 16× clock).
LEVEL_OVERSAMPLING: Final = 16


def cycles_per_bit(baud: int) -> int:
    """Clock cycles per bit: the UART's divider counts whole cycles."""
    if baud <= 0:
        raise ValueError(f"baud must be positive, got {baud}")
    return round(CLOCK_HZ / baud)


class ByteRun:
    """Bytes received back to back: byte ``i`` completed (stop bit ended) at cycle
    ``first + i * step``. A plain class (not a dataclass, whose ``__init__`` is Python code
    in either build): one is made for every frame in each direction."""

    __slots__ = ("data", "first", "step")

    def __init__(self, data: bytes, first: int, step: int) -> None:
        self.data = data
        self.first = first
        self.step = step

    def __repr__(self) -> str:
        return f"ByteRun(data={self.data!r}, first={self.first}, step={self.step})"

    def cycle_of(self, index: int) -> int:
        return self.first + index * self.step

    @property
    def last(self) -> int:
        """Completion cycle of the last byte."""
        return self.first + (len(self.data) - 1) * self.step

    def completed_by(self, cycle: int) -> int:
        """How many of the bytes have completed at ``cycle``."""
        if cycle < self.first:
            return 0
        return min(len(self.data), (cycle - self.first) // self.step + 1)

    def timed(self) -> list[tuple[int, int]]:
        """``(byte, completion cycle)`` pairs."""
        first, step = self.first, self.step
        return [(b, first + i * step) for i, b in enumerate(self.data)]


@dataclass
class LineFaults:
    """Faults on one line direction. Byte indexes count the bytes the sender put on this line
    since power-up, from 0 (inserted noise not counted); bit indexes are slots 0..9 of a byte
    (:data:`BIT_START`, data bit k at k + 1, :data:`BIT_STOP`)."""

    #: ``(byte index, bit index)`` pairs to invert.
    flip_bits: set[tuple[int, int]] = field(default_factory=set)
    #: byte indexes whose stop bit reads low: a framing error, the byte is lost.
    break_stop: set[int] = field(default_factory=set)
    #: byte indexes that never reach the receiver (the line stays idle for their time).
    drop: set[int] = field(default_factory=set)
    #: bytes put on the wire just before the sender's byte of this index (they take line time).
    noise: dict[int, bytes] = field(default_factory=dict)
    #: probability that any one bit slot (noise included) is inverted.
    bit_error_rate: float = 0.0
    #: probability that each sender byte is lost (the line stays idle for its time).
    drop_rate: float = 0.0
    #: probability that each sender byte goes on the wire twice (the copy takes line time).
    dup_rate: float = 0.0
    #: probability that a burst of ``noise_len`` random bytes precedes each sender byte.
    noise_rate: float = 0.0
    #: at most :data:`~fpgalink.protocol.faults.MAX_NOISE_LEN`: a burst is laid out bit by
    #: bit, noise and all, so this bounds the memory a burst can take
    noise_len: int = 1
    #: ``[start, end)`` cycle windows in which the line is held low (a break): every slot
    #: sent then reads 0, so the receiver sees zero bytes with framing errors.
    stuck: list[tuple[int, int]] = field(default_factory=list)
    #: ``[start, end)`` cycle windows in which the line is cut (reads idle high): bytes sent
    #: then never arrive — an unplugged cable, or a stalled peer as the receiver sees it.
    cut: list[tuple[int, int]] = field(default_factory=list)

    def __post_init__(self) -> None:
        for name in ("bit_error_rate", "drop_rate", "dup_rate", "noise_rate"):
            rate = getattr(self, name)
            if not 0.0 <= rate <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {rate}")
        if not 1 <= self.noise_len <= MAX_NOISE_LEN:  # the --fault grammar's bound
            raise ValueError(f"noise_len must be 1..{MAX_NOISE_LEN}, got {self.noise_len}")
        for _, bit in self.flip_bits:
            if not 0 <= bit < BITS_PER_BYTE:
                raise ValueError(f"bit index {bit} is not a slot 0..9 of an 8N1 byte")
        for start, end in (*self.stuck, *self.cut):
            if not 0 <= start <= end:
                raise ValueError(f"fault window [{start}, {end}) is not a cycle range")

    def touches(self, first: int, end: int) -> bool:
        """Whether an index-based fault applies to sender bytes ``first <= index < end``
        (rate and window faults are decided per burst by the line)."""
        for index in (*self.break_stop, *self.drop, *self.noise):
            if first <= index < end:
                return True
        return any(first <= index < end for index, _ in self.flip_bits)

    def windows_overlap(self, start: int, end: int) -> bool:
        """Whether a stuck or cut window overlaps cycles ``[start, end)``."""
        return any(a < end and start < b for a, b in (*self.stuck, *self.cut))

    @property
    def random(self) -> bool:
        return (self.bit_error_rate > 0.0 or self.drop_rate > 0.0 or self.dup_rate > 0.0
                or self.noise_rate > 0.0)


@dataclass(slots=True)
class LineStats:
    bytes_sent: int = 0  #: bytes the sender put on the line (noise excluded)
    bytes_received: int = 0  #: bytes the receiver delivered
    framing_errors: int = 0  #: bytes the receiver dropped for a low stop bit
    bits_flipped: int = 0
    noise_bytes: int = 0
    dropped_bytes: int = 0  #: sender bytes lost by ``LineFaults.drop`` or a frame filter
    duplicated_bytes: int = 0  #: extra copies put on the wire by ``LineFaults.dup_rate``
    stuck_slots: int = 0  #: bit slots forced low by a stuck-line window
    cut_slots: int = 0  #: bit slots forced idle by a cut-line window


def _byte_slots(value: int) -> list[int]:
    return [0, *((value >> k) & 1 for k in range(8)), 1]


def _indexes(rng: np.random.Generator, count: int, rate: float) -> list[int]:
    """Indexes ``0 <= i < count`` hit at ``rate``; draws nothing when the rate is 0, so a
    fault that is off leaves every generator's stream where it was."""
    if rate <= 0.0:
        return []
    hits: list[int] = (rng.random(count) < rate).nonzero()[0].tolist()
    return hits


@dataclass(slots=True)
class _Plan:
    """Random byte-level decisions for one burst (offsets into the burst)."""

    drop: set[int]
    dup: set[int]
    noise: dict[int, bytes]

    def __bool__(self) -> bool:
        return bool(self.drop or self.dup or self.noise)


def litex_sample_points(cycles_per_bit: int) -> tuple[tuple[int, ...], int]:
    """Where LiteX's ``RS232PHYRX`` samples a frame, in cycles after the falling edge of its
    start bit: the pad level read for the start bit, the eight data bits and the stop bit
    (10 points), and the earliest cycle a falling edge can start the next byte (it returns
    to hunting the cycle after the stop sample and sees an edge 2 cycles late).

    Its 2-FF synchroniser and edge register see the edge 2 cycles late and run from edge +
    3; a phase accumulator preset to 2³¹ adds ``int(2³²/cpb)`` each cycle and ticks on
    overflow; each tick samples the synchronised line (the pad 2 cycles earlier). At 100
    cycles per bit: 52, 152, … 952, and hunting resumes at 955."""
    word = int(2**32 / cycles_per_bit)
    cycle, phase, samples = 3, 2**31, []
    for _ in range(BITS_PER_BYTE):
        ticks = -(-(2**32 - phase) // word)
        cycle += ticks
        phase += ticks * word - 2**32
        samples.append(cycle - 2)
    return tuple(samples), cycle + 1 - 2


class SlotReceiver:
    """An 8N1 receiver that is a function of the line's waveform alone (see the module
    docstring). The waveform is given as bursts of bit slots (:meth:`add`), each starting
    no earlier than the previous one ended; between bursts the line is idle (high).
    :meth:`decide` returns the bytes whose samples all lie before a cycle up to which the
    waveform is known; the rest waits for more waveform or for time to pass."""

    __slots__ = ("_bursts", "_hunt", "_resume", "_samples", "_tail_end", "_tail_level", "bit",
                 "framing_errors", "on_framing_error")

    def __init__(self, cycles_per_bit: int) -> None:
        self.bit = cycles_per_bit
        self._samples, self._resume = litex_sample_points(cycles_per_bit)
        self._bursts: deque[tuple[int, list[int]]] = deque()
        self._hunt = 0  #: the earliest cycle a falling edge starts a byte at
        #: where the slots already forgotten ended, and the level they ended on
        self._tail_end = -1
        self._tail_level = 1
        self.framing_errors = 0
        #: called with the cycle a dropped byte's stop bit ends (a logic analyser, a test)
        self.on_framing_error: Callable[[int], None] | None = None

    @property
    def pending(self) -> bool:
        """Slots are held that may still start or complete a byte."""
        return bool(self._bursts)

    def add(self, start: int, slots: list[int]) -> None:
        self._bursts.append((start, slots))

    def _level(self, cycle: int) -> int:
        for start, slots in self._bursts:
            if cycle < start:
                return 1
            index = (cycle - start) // self.bit
            if index < len(slots):
                return slots[index]
        return 1

    def _next_edge(self) -> int | None:
        """The first falling edge at or after the hunting point, in the held slots."""
        bit = self.bit
        for number, (start, slots) in enumerate(self._bursts):
            first = max(0, -(-(self._hunt - start) // bit))
            for j in range(first, len(slots)):
                if slots[j]:
                    continue
                edge = start + j * bit
                before = slots[j - 1] if j else (
                    self._level(edge - 1) if number else self._idle_before(edge))
                if before:
                    return edge
        return None

    def _idle_before(self, edge: int) -> int:
        return 1 if edge > self._tail_end else self._tail_level

    def decide(self, known_until: int) -> list[tuple[int, int]]:
        """``(byte, delivery cycle)`` for every byte decided from the waveform known up to
        ``known_until`` (beyond the held slots and before it, the line is idle)."""
        out: list[tuple[int, int]] = []
        bit, samples = self.bit, self._samples
        while self._bursts:
            edge = self._next_edge()
            if edge is None:
                self._drop_before(self._bursts[-1][0] + len(self._bursts[-1][1]) * bit)
                break
            if edge + samples[-1] >= known_until:
                self._drop_before(edge)
                break
            value = 0
            for k in range(8):
                if self._level(edge + samples[k + 1]):
                    value |= 1 << k
            if self._level(edge + samples[9]):
                out.append((value, edge + BITS_PER_BYTE * bit))
            else:
                self.framing_errors += 1
                if self.on_framing_error is not None:
                    self.on_framing_error(edge + BITS_PER_BYTE * bit)
            self._hunt = edge + self._resume
            self._drop_before(self._hunt)
        return out

    def next_decision(self) -> int | None:
        """The cycle at which a held byte is decided if nothing more is sent: the end of its
        stop bit; ``None`` when no byte is under way."""
        edge = self._next_edge()
        return None if edge is None else edge + BITS_PER_BYTE * self.bit

    def _drop_before(self, cycle: int) -> None:
        """Forget slots that end before ``cycle`` (keeping what edge detection needs)."""
        bit = self.bit
        while self._bursts:
            start, slots = self._bursts[0]
            end = start + len(slots) * bit
            if end > cycle:
                break
            self._tail_end, self._tail_level = end, slots[-1] if slots else 1
            self._bursts.popleft()

    def cut_from(self, cycle: int) -> None:
        """The sender went away at ``cycle``: slots of bursts that had not begun are gone."""
        while self._bursts and self._bursts[-1][0] >= cycle:
            self._bursts.pop()


class LevelReceiver(SlotReceiver):
    """A level-triggered 8N1 receiver, a function of the waveform alone like
    :class:`SlotReceiver`: while idle it starts a byte on any cycle its synchronised input is
    low (not only on a falling edge), checks the start bit again at mid-bit (a high start bit
    was a glitch: back to idle), then samples each bit at its middle on a free-running 16×
    clock and drops a byte whose stop bit reads low (a framing error). It hunts again from
    the cycle after the stop sample, so a line still low there (a low stop bit, a break)
    starts the next byte at once: a break gives a framing error every byte time.

    This is OpenTitan's ``uart_rx`` (lowRISC, Apache-2.0; checked against that RTL in
    ``tests/fpgaemu/test_uart_hdl.py``) behind a two-flip-flop synchroniser, with its 16×
    tick from a free-running divider that spreads 16 ticks evenly over each ``cycles_per_bit``
    cycles from power-up (tick in cycle c when ⌊16(c+1)/cpb⌋ > ⌊16c/cpb⌋); verilog-uart's
    ``uart_rx`` and a 16550 behave the same way (start on a low level, mid-bit re-check),
    with their own clocks. A byte is delivered at the end of its nominal stop bit (its start
    plus ten bit times), as :class:`SlotReceiver` delivers."""

    __slots__ = ()

    def _tick_after(self, cycle: int, count: int) -> int:
        """The cycle of the ``count``-th 16× tick after ``cycle``."""
        bit, over = self.bit, LEVEL_OVERSAMPLING
        ticks = (cycle + 1) * over // bit + count
        return -(-ticks * bit // over) - 1

    def _next_start(self) -> int | None:
        """The first cycle at or after the hunting point at which the synchronised input is
        low, in the held slots."""
        bit = self.bit
        first_level = self._hunt - LEVEL_SYNC_CYCLES
        for start, slots in self._bursts:
            end = start + len(slots) * bit
            if end <= first_level:
                continue
            j = max(0, (first_level - start) // bit)
            for k in range(j, len(slots)):
                if not slots[k]:
                    return max(first_level, start + k * bit) + LEVEL_SYNC_CYCLES
        return None

    def _sample_cycles(self, start: int) -> list[int]:
        """The cycles at which the byte started at ``start`` reads its ten bits (each reads
        the line :data:`LEVEL_SYNC_CYCLES` earlier): the cycle after every 16th tick, from
        the 8th."""
        return [self._tick_after(start, 8 + 16 * i) + 1 for i in range(BITS_PER_BYTE)]

    def decide(self, known_until: int) -> list[tuple[int, int]]:
        out: list[tuple[int, int]] = []
        bit, sync = self.bit, LEVEL_SYNC_CYCLES
        while self._bursts:
            start = self._next_start()
            if start is None:
                self._drop_before(self._bursts[-1][0] + len(self._bursts[-1][1]) * bit)
                break
            samples = self._sample_cycles(start)
            if samples[0] - sync >= known_until:
                self._drop_before(start - sync)
                break
            if self._level(samples[0] - sync):  # a glitch: the start bit is gone at mid-bit
                self._hunt = samples[0] + 1
                self._drop_before(self._hunt - sync - 1)
                continue
            if samples[-1] - sync >= known_until:
                self._drop_before(start - sync)
                break
            value = 0
            for k in range(8):
                if self._level(samples[k + 1] - sync):
                    value |= 1 << k
            done = start - sync + BITS_PER_BYTE * bit
            if self._level(samples[9] - sync):
                out.append((value, done))
            else:
                self.framing_errors += 1
                if self.on_framing_error is not None:
                    self.on_framing_error(done)
            self._hunt = samples[9] + 1
            self._drop_before(self._hunt - sync - 1)
        return out

    def next_decision(self) -> int | None:
        start = self._next_start()
        if start is None:
            return None
        return max(start - LEVEL_SYNC_CYCLES + BITS_PER_BYTE * self.bit,
                   self._sample_cycles(start)[-1] - LEVEL_SYNC_CYCLES + 1)


_NO_PLAN: Final = _Plan(set(), set(), {})
#: a line with no faults, for a clean burst that must go through the slots
_CLEAN: Final = LineFaults()


class _Line:
    """The sender-to-receiver path of one direction: timing, queuing and faults."""

    __slots__ = (
        "_decision",
        "_last_level",
        "_rng",
        "_rng_drop",
        "_rng_dup",
        "_rng_noise",
        "_timeline",
        "baud",
        "byte_gap",
        "byte_step",
        "cycles_per_bit",
        "cycles_per_byte",
        "faults",
        "line_free_at",
        "name",
        "receiver",
        "stats",
    )

    def __init__(
        self, timeline: Timeline, name: str, baud: int, faults: LineFaults | None,
        byte_gap: int = 0, rx_mode: str = "edge",
    ) -> None:
        if rx_mode not in UART_RX_MODES:
            raise ValueError(f"rx_mode must be one of {', '.join(UART_RX_MODES)}, got "
                             f"{rx_mode!r}")
        if byte_gap < 0:
            raise ValueError(f"byte_gap must be ≥ 0 cycles, got {byte_gap}")
        self._timeline = timeline
        self.name = name
        self.baud = baud
        self.cycles_per_bit = cycles_per_bit(baud)
        self.cycles_per_byte = BITS_PER_BYTE * self.cycles_per_bit
        #: idle cycles the sender leaves after each byte's stop bit, back to back
        self.byte_gap = byte_gap
        #: start-to-start spacing of back-to-back bytes
        self.byte_step = self.cycles_per_byte + byte_gap
        self.faults = faults
        self.stats = LineStats()
        #: cycle at which the last queued byte's stop bit ends; the line is idle from then.
        self.line_free_at = 0
        #: the line level at ``line_free_at`` (a burst can end low)
        self._last_level = 1
        self.receiver = (LevelReceiver if rx_mode == "level" else SlotReceiver)(
            self.cycles_per_bit)
        self._decision: Any = None
        rng: Any = timeline.rng if faults is not None else (lambda _name: None)
        self._rng = rng(name)
        self._rng_drop = rng(name + ".drop")
        self._rng_dup = rng(name + ".dup")
        self._rng_noise = rng(name + ".noise")

    @property
    def busy(self) -> bool:
        return self._timeline.now < self.line_free_at

    def _send(self, data: bytes, cycle: int | None, lost: bool = False) -> list[ByteRun]:
        """Put ``data`` on the line at ``cycle`` (default now), behind anything queued;
        ``lost`` bytes take their line time but never reach the receiver."""
        now = self._timeline.now
        at = now if cycle is None else cycle
        if at < now:
            raise ValueError(f"{self.name}: cannot send at cycle {at}, the present is {now}")
        start = max(at, self.line_free_at)
        stats = self.stats
        index = stats.bytes_sent
        n = len(data)
        stats.bytes_sent += n
        step = self.byte_step
        if lost:
            self.line_free_at = start + n * step - self.byte_gap
            self._last_level = 1
            stats.dropped_bytes += n
            return self._idle_until(start)
        faults = self.faults
        plan = _NO_PLAN
        hits = None
        if faults is not None:
            plan = _Plan(
                set(_indexes(self._rng_drop, n, faults.drop_rate)),
                set(_indexes(self._rng_dup, n, faults.dup_rate)),
                {
                    k: self._rng_noise.integers(0, 256, faults.noise_len, "uint8").tobytes()
                    for k in _indexes(self._rng_noise, n, faults.noise_rate)
                },
            )
            if plan or faults.touches(index, index + n):
                return self._send_bitwise(data, start, index, faults, plan, None)
            if faults.bit_error_rate > 0.0:
                # Same draw the bit-level path would make for this burst, made first so a
                # burst with no hit stays on the fast path.
                hits = self._rng.random(n * BITS_PER_BYTE) < faults.bit_error_rate
                if hits.any():
                    return self._send_bitwise(data, start, index, faults, plan, hits)
            if faults.windows_overlap(start, start + n * step):
                return self._send_bitwise(data, start, index, faults, plan, hits)
        if self.receiver.pending or (start == self.line_free_at and not self._last_level):
            # The receiver is mid-byte, or the line is still low from the last burst: the
            # first start bit is not a clean edge, so the slots decide.
            return self._send_bitwise(data, start, index, faults or _CLEAN, plan, hits)
        self.line_free_at = start + n * step - self.byte_gap
        self._last_level = 1
        stats.bytes_received += n
        return [ByteRun(data, start + self.cycles_per_byte, step)]

    def _idle_until(self, start: int) -> list[ByteRun]:
        """The line idles (high) from ``start``: whatever the receiver held is decided."""
        if not self.receiver.pending:
            return []
        return self._decided(start)

    def _send_bitwise(
        self, data: bytes, start: int, index: int, faults: LineFaults, plan: _Plan,
        hits: np.ndarray[tuple[int], np.dtype[np.bool_]] | None,
    ) -> list[ByteRun]:
        stats = self.stats
        flips: dict[int, list[int]] = {}
        for byte_index, bit in faults.flip_bits:
            flips.setdefault(byte_index, []).append(bit)
        for byte_index in faults.break_stop:
            flips.setdefault(byte_index, []).append(BIT_STOP)
        slots: list[int] = []
        for k, value in enumerate(data):
            i = index + k
            noise = faults.noise.get(i, b"") + plan.noise.get(k, b"")
            if noise:
                stats.noise_bytes += len(noise)
                for n in noise:
                    slots += _byte_slots(n)
            if i in faults.drop or k in plan.drop:
                stats.dropped_bytes += 1
                slots += [1] * BITS_PER_BYTE
                continue
            bits = _byte_slots(value)
            for bit in set(flips.get(i, ())):
                bits[bit] ^= 1
                stats.bits_flipped += 1
            slots += bits
            if k in plan.dup:
                stats.duplicated_bytes += 1
                slots += _byte_slots(value)
        if faults.bit_error_rate > 0.0:
            if hits is None or len(hits) != len(slots):
                hits = self._rng.random(len(slots)) < faults.bit_error_rate
            for slot in hits.nonzero()[0].tolist():
                slots[slot] ^= 1
                stats.bits_flipped += 1
        bit = self.cycles_per_bit
        if self.byte_gap:
            # Each wire byte on its own, ``byte_step`` apart: the gap is idle line.
            at = start
            for first in range(0, len(slots), BITS_PER_BYTE):
                piece = slots[first:first + BITS_PER_BYTE]
                self._apply_windows(piece, at, faults)
                self.receiver.add(at, piece)
                at += self.byte_step
            self.line_free_at = at - self.byte_gap
        else:
            self._apply_windows(slots, start, faults)
            self.receiver.add(start, slots)
            self.line_free_at = start + len(slots) * bit
        self._last_level = slots[-1] if slots else 1
        return self._decided(self.line_free_at)

    def _decided(self, known_until: int) -> list[ByteRun]:
        """What the receiver can decide with the waveform known up to ``known_until``, as
        runs of evenly spaced bytes; a byte still under way is decided later (when the next
        burst arrives, or at the end of its stop bit)."""
        receiver = self.receiver
        before = receiver.framing_errors
        received = receiver.decide(known_until)
        self.stats.framing_errors += receiver.framing_errors - before
        self.stats.bytes_received += len(received)
        self._schedule_decision()
        runs: list[ByteRun] = []
        group = bytearray()
        first = previous = -1
        for value, done in received:
            if group and done != previous + self.byte_step:
                runs.append(ByteRun(bytes(group), first, self.byte_step))
                group.clear()
            if not group:
                first = done
            group.append(value)
            previous = done
        if group:
            runs.append(ByteRun(bytes(group), first, self.byte_step))
        return runs

    def _schedule_decision(self) -> None:
        if self._decision is not None:
            self._decision.cancel()
            self._decision = None
        due = self.receiver.next_decision()
        if due is not None:
            self._decision = self._timeline.schedule(max(due, self._timeline.now),
                                                     self._decide_now)

    def _decide_now(self, cycle: int) -> None:
        """Nothing more was sent: the line idled, and a held byte is decided."""
        self._decision = None
        self._deliver(self._decided(cycle))

    def _deliver(self, runs: list[ByteRun]) -> None:
        raise NotImplementedError  # each direction hands runs on its own way

    def _apply_windows(self, slots: list[int], start: int, faults: LineFaults) -> None:
        """Force the slots sent inside stuck windows low and inside cut windows high. A
        slot counts as inside when its bit period begins in the window."""
        bit = self.cycles_per_bit
        n = len(slots)
        for windows, level in ((faults.cut, 1), (faults.stuck, 0)):
            for a, b in windows:
                first = max(0, -(-(a - start) // bit))
                end = min(n, -(-(b - start) // bit))
                if first >= end:
                    continue
                slots[first:end] = [level] * (end - first)
                if level:
                    self.stats.cut_slots += end - first
                else:
                    self.stats.stuck_slots += end - first


class UartRead(_Line):
    """Host → board: the host's bytes on the RX pin, delivered as :class:`ByteRun`\\ s to the
    ``sink`` (``uartcommand``) when they are put on the line, with their completion cycles."""

    __slots__ = ("sink",)

    def __init__(
        self,
        timeline: Timeline,
        sink: Callable[[ByteRun], None],
        baud: int = DEFAULT_BAUD,
        faults: LineFaults | None = None,
        rx_mode: str = "edge",
    ) -> None:
        super().__init__(timeline, "uartread", baud, faults, rx_mode=rx_mode)
        self.sink = sink

    def transmit(self, data: bytes | bytearray | memoryview, cycle: int | None = None) -> int:
        """The host writes ``data`` starting at ``cycle`` (default now); returns the cycle the
        last byte's stop bit ends."""
        if not data:
            return max(self._timeline.now, self.line_free_at)
        self._deliver(self._send(bytes(data), cycle))
        return self.line_free_at

    def _deliver(self, runs: list[ByteRun]) -> None:
        for run in runs:
            self.sink(run)


class UartWrite(_Line):
    """Board → host: bytes leave back to back at line rate; the host side drains those whose
    stop bit has ended (:meth:`read_completed`). Listeners see each run when it is committed
    to the wire, with its future completion cycles (a logic analyser, a budget meter)."""

    __slots__ = ("_head_taken", "_listeners", "_pending")

    def __init__(
        self, timeline: Timeline, baud: int = DEFAULT_BAUD, faults: LineFaults | None = None,
        byte_gap: int = 0,
    ) -> None:
        super().__init__(timeline, "uartwrite", baud, faults, byte_gap)
        #: runs on their way to the host; only the first can be partly handed out
        self._pending: deque[ByteRun] = deque()
        self._head_taken = 0  #: bytes of the first pending run already handed out
        self._listeners: list[Callable[[ByteRun], None]] = []

    def add_listener(self, listener: Callable[[ByteRun], None]) -> None:
        self._listeners.append(listener)

    def transmit(
        self, data: bytes | bytearray | memoryview, cycle: int | None = None, *,
        lost: bool = False,
    ) -> int:
        """Serialise ``data`` from ``cycle`` (default now), behind anything still on the line;
        returns the cycle the last stop bit ends. ``lost``: a fault hook's dropped frame —
        it occupies the line but the host never sees it."""
        if not data:
            return max(self._timeline.now, self.line_free_at)
        self._deliver(self._send(data if type(data) is bytes else bytes(data), cycle, lost))
        return self.line_free_at

    def _deliver(self, runs: list[ByteRun]) -> None:
        for run in runs:
            self._pending.append(run)
            for listener in self._listeners:
                listener(run)

    @property
    def next_completion(self) -> int | None:
        """The cycle the run of bytes now on the wire completes (its last stop bit), or
        ``None``: a reader that waits for whole runs (frames) wakes once per frame."""
        pending = self._pending
        return pending[0].last if pending else None

    def read_completed(self, cycle: int | None = None) -> bytes:
        """Drain the bytes whose stop bit has ended by ``cycle`` (default now)."""
        out = bytearray()
        for run, taken, done in self._drain(cycle):
            out += run.data[taken:done]
        return bytes(out)

    def read_completed_runs(self, cycle: int | None = None) -> bytes:
        """As :meth:`read_completed`, a run (a frame, or the part of one between two of a
        fault's gaps) only once its last stop bit has ended by ``cycle`` (default now):
        what has ended of the run still on the wire waits, whole, for its end."""
        at = self._timeline.now if cycle is None else cycle
        pending = self._pending
        out = bytearray()
        while pending and pending[0].last <= at:
            run = pending.popleft()
            out += run.data[self._head_taken:] if self._head_taken else run.data
            self._head_taken = 0
        return bytes(out)

    @property
    def oldest_unread(self) -> int | None:
        """The cycle the oldest byte not read yet ends (or ended), ``None`` for none."""
        pending = self._pending
        if not pending:
            return None
        run = pending[0]
        return run.first + self._head_taken * run.step

    def read_completed_timed(self, cycle: int | None = None) -> list[tuple[int, int]]:
        """As :meth:`read_completed`, as ``(byte, completion cycle)`` pairs."""
        out: list[tuple[int, int]] = []
        for run, taken, done in self._drain(cycle):
            out += [(run.data[i], run.first + i * run.step) for i in range(taken, done)]
        return out

    def _drain(self, cycle: int | None) -> Iterator[tuple[ByteRun, int, int]]:
        """Each pending run with bytes ``taken:done`` newly completed by ``cycle`` (default
        now), handed out as the caller takes them."""
        at = self._timeline.now if cycle is None else cycle
        pending = self._pending
        while pending:
            run, taken = pending[0], self._head_taken
            done = run.completed_by(at)
            if done > taken:
                yield run, taken, done
            if done < len(run.data):
                self._head_taken = done
                return
            pending.popleft()
            self._head_taken = 0
