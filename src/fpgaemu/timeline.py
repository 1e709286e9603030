"""The integer-cycle event kernel every emulated module runs on.

Time is a count of 100 MHz clock cycles. Nothing steps idle cycles: the timeline keeps a heap
of deadlines and jumps straight to the next one, so an idle second costs nothing and a busy
one costs one Python call per *event* (a frame, a timer tick), never per cycle or per bit.

Ordering is fully deterministic. Events of one cycle run in two phases: every ordinary event
first, then every ``late`` event (a sampler that must see the cycle's settled state, like a
register read at the clock edge after all logic of the cycle has updated). Within a phase,
ties are broken by scheduling order. Randomness comes only from generators derived from the
board's seed and a consumer name, so adding a consumer never shifts another's stream.
"""

from __future__ import annotations

import heapq
import zlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Final

if TYPE_CHECKING:  # numpy loads only when a consumer asks for randomness
    import numpy as np

__all__ = [
    "CLOCK_HZ",
    "Callback",
    "EventHandle",
    "Timeline",
    "cycles_to_seconds",
    "ms",
    "seconds_to_cycles",
    "us",
]

#: The CmodA7 oscillator the whole design is clocked from.
CLOCK_HZ: Final = 100_000_000
_CYCLES_PER_MS: Final = CLOCK_HZ // 1000
_CYCLES_PER_US: Final = CLOCK_HZ // 1_000_000


def ms(milliseconds: int | float) -> int:
    """Cycles in ``milliseconds`` (exact for whole numbers: 1 ms is 100,000 cycles)."""
    if isinstance(milliseconds, int):
        return milliseconds * _CYCLES_PER_MS
    return round(milliseconds * _CYCLES_PER_MS)


def us(microseconds: int | float) -> int:
    """Cycles in ``microseconds`` (1 µs is 100 cycles)."""
    if isinstance(microseconds, int):
        return microseconds * _CYCLES_PER_US
    return round(microseconds * _CYCLES_PER_US)

#: An event callback receives the cycle it runs at.
Callback = Callable[[int], None]

_EARLY: Final = 0
_LATE: Final = 1


def seconds_to_cycles(seconds: float) -> int:
    """Nearest whole cycle; durations in the seed are given in seconds or milliseconds."""
    return round(seconds * CLOCK_HZ)


def cycles_to_seconds(cycles: int) -> float:
    return cycles / CLOCK_HZ


class EventHandle:
    """A scheduled event; ``cancel()`` makes it a no-op (it is dropped lazily from the heap,
    which keeps cancel O(1) — the watchdog is re-armed on every ``RE``)."""

    __slots__ = ("callback", "cancelled", "cycle")

    def __init__(self, cycle: int, callback: Callback) -> None:
        self.cycle = cycle
        self.callback = callback
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True

    @property
    def pending(self) -> bool:
        return not self.cancelled

    def __repr__(self) -> str:
        state = "cancelled" if self.cancelled else "pending"
        return f"<EventHandle cycle={self.cycle} {state}>"


class Timeline:
    """Heap of ``(cycle, phase, seq, handle)``; ``now`` only ever moves forward."""

    __slots__ = ("_heap", "_running", "_seq", "now", "seed")

    def __init__(self, seed: int = 0) -> None:
        self.now = 0
        self.seed = seed
        self._heap: list[tuple[int, int, int, EventHandle]] = []
        self._seq = 0
        self._running = False

    # --- scheduling -----------------------------------------------------------------------

    def schedule(self, cycle: int, callback: Callback, *, late: bool = False) -> EventHandle:
        """Run ``callback(cycle)`` at ``cycle`` (not before ``now``; at ``now`` while the
        timeline is running means later in this same cycle)."""
        if cycle < self.now:
            raise ValueError(f"cannot schedule at cycle {cycle}: the present is {self.now}")
        handle = EventHandle(cycle, callback)
        self._seq += 1
        heapq.heappush(self._heap, (cycle, _LATE if late else _EARLY, self._seq, handle))
        return handle

    def schedule_in(self, delay: int, callback: Callback, *, late: bool = False) -> EventHandle:
        return self.schedule(self.now + delay, callback, late=late)

    @property
    def next_deadline(self) -> int | None:
        """Cycle of the next pending event, or ``None`` when nothing is scheduled."""
        heap = self._heap
        while heap and heap[0][3].cancelled:
            heapq.heappop(heap)
        return heap[0][0] if heap else None

    def next_deadline_except(self, skippable: EventHandle | None) -> int | None:
        """:attr:`next_deadline`, not counting ``skippable`` (an event known to change
        nothing observable, such as a quiescent board's timer tick): a scan of the pending
        events, which are few."""
        if skippable is None:
            return self.next_deadline
        best: int | None = None
        for at, _, _, handle in self._heap:
            if handle is skippable or handle.cancelled:
                continue
            if best is None or at < best:
                best = at
        return best

    # --- running --------------------------------------------------------------------------

    def run_until(self, cycle: int) -> None:
        """Run every event due at or before ``cycle``, then stand at ``cycle``."""
        if cycle < self.now:
            raise ValueError(f"cannot run back to cycle {cycle}: the present is {self.now}")
        if self._running:
            raise RuntimeError("run_until called from inside an event")
        heap = self._heap
        pop = heapq.heappop
        self._running = True
        try:
            while heap and heap[0][0] <= cycle:
                at, _, _, handle = pop(heap)
                if handle.cancelled:
                    continue
                handle.cancelled = True  # fired: a later cancel() is harmless
                self.now = at
                handle.callback(at)
        finally:
            self._running = False
        self.now = cycle

    def run_for(self, seconds: float) -> None:
        self.run_until(self.now + seconds_to_cycles(seconds))

    def run_cycles(self, cycles: int) -> None:
        self.run_until(self.now + cycles)

    # --- randomness -----------------------------------------------------------------------

    def rng(self, consumer: str) -> np.random.Generator:
        """An independent generator for one consumer, fixed by the board's seed and the
        consumer's name: two boards with one seed draw identical streams."""
        import numpy as np

        return np.random.default_rng([self.seed & 0xFFFF_FFFF, zlib.crc32(consumer.encode())])
