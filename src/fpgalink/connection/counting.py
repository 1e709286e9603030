"""The board's message counter, followed: gaps, duplicates and late arrivals are events and
counts; a sequence starting again (back to ``00000``, or counting on from behind) is a
restart, not copies. A message the router made (:func:`from_router`) is no part of the
sequence."""

from __future__ import annotations

from collections.abc import Callable

from fpgalink.connection.stats import LinkStats
from fpgalink.events import CounterDuplicate, CounterGap, CounterLate
from fpgalink.protocol import (
    COUNTER_MODULUS,
    CounterTracker,
    Event,
    NackReason,
    Observation,
    ParamNack,
)

__all__ = ["Counting", "from_router"]


def from_router(msg: object) -> bool:
    """``msg`` is ``fpgalink-cli router``'s answer, not the board's: a ``PN`` with code 5
    (:attr:`~fpgalink.protocol.NackReason.NOT_CONTROLLER`, a client that does not control
    the board refused). The router counts its own (from ``00000``): no part of the board's
    counter sequence, and no sign that the board is there."""
    return type(msg) is ParamNack and msg.error == NackReason.NOT_CONTROLLER


class Counting:
    """The counter tracker of one link (``tracker``) and what it finds, said."""

    __slots__ = ("_emit", "_last_duplicate", "_stats", "tracker")

    def __init__(self, stats: LinkStats, emit: Callable[[Event], None]) -> None:
        self.tracker = CounterTracker()
        self._last_duplicate: int | None = None
        self._stats = stats
        self._emit = emit

    def judge(self, counter: int) -> tuple[Observation, str | None]:
        """Observe ``counter``, not the one expected (the wrap included: the tracker's to
        judge). A sequence starting again comes back with the restart's detail, taken off
        the duplicates: the caller restarts, then counts from ``counter``."""
        tracker = self.tracker
        expected = tracker.expected
        observation = tracker.observe(counter)
        if observation is not Observation.DUPLICATE:
            self._last_duplicate = None
            return observation, None
        previous, self._last_duplicate = self._last_duplicate, counter
        run = previous == (counter - 1) % COUNTER_MODULUS
        if counter == 0 or run:
            tracker.duplicates -= 1 + run
            self._stats.duplicates -= run
            return observation, f"counter {counter:05d} where {expected:05d} was expected"
        return observation, None

    def say(self, observation: Observation, counter: int) -> None:
        tracker, stats = self.tracker, self._stats
        if observation is Observation.GAP:
            self._emit(CounterGap(tracker.last_gap, counter))
        elif observation is Observation.DUPLICATE:
            stats.duplicates += 1
            self._emit(CounterDuplicate(counter))
        elif observation is Observation.LATE:
            stats.reordered += 1
            self._emit(CounterLate(counter))
        elif observation is Observation.CORRUPT:
            stats.corrupt_counters += 1
        stats.lost = tracker.lost

    def restarted(self) -> None:
        """The board restarted: a new sequence."""
        self.tracker.reset()
        self._last_duplicate = None
