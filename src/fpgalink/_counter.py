"""Message counters (SPEC §4): the sender's wrapping counter and the receiver's tracker that
turns the counters it sees into lost / duplicated / reordered counts."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from fpgalink._messages import COUNTER_MODULUS

__all__ = ["CounterTracker", "Observation", "SendCounter"]

#: How far back a counter is still "recent": older ones are judged duplicates of something
#: long gone. Half the counter space, so the wrap never looks like a jump backwards.
_HALF = COUNTER_MODULUS // 2
#: How many missing counters are remembered, so a late arrival is recognised as reordered.
_MISSING_WINDOW = 4096


class SendCounter:
    """Each counted message a side sends takes the next value, resends included."""

    __slots__ = ("value",)

    def __init__(self, start: int = 0) -> None:
        self.value = start % COUNTER_MODULUS

    def take(self) -> int:
        value = self.value
        self.value = (value + 1) % COUNTER_MODULUS
        return value


class Observation(Enum):
    FIRST = "first"  #: the first counter seen on this link
    IN_ORDER = "in_order"
    GAP = "gap"  #: counters were skipped: that many messages lost (so far)
    LATE = "late"  #: a counter earlier reported missing arrived after all (reordered)
    DUPLICATE = "duplicate"


@dataclass(slots=True)
class CounterTracker:
    """Receiver side. ``observe(counter)`` classifies each arrival. A jump ahead of less than
    half the counter space is a gap (those messages are counted skipped); anything behind is
    a late arrival if it was one of the skipped, else a duplicate. ``lost`` is the net."""

    expected: int | None = None
    received: int = 0
    skipped: int = 0  #: counters jumped over (each counted once, when the jump is seen)
    late: int = 0  #: skipped counters that arrived afterwards (reordering)
    duplicates: int = 0
    last_gap: int = 0
    _missing: dict[int, None] = field(default_factory=dict, repr=False)

    @property
    def lost(self) -> int:
        """Messages skipped and not (yet) seen: the net loss."""
        return self.skipped - self.late

    def observe(self, counter: int) -> Observation:
        self.received += 1
        expected = self.expected
        if expected == counter:
            self.expected = (counter + 1) % COUNTER_MODULUS
            return Observation.IN_ORDER
        if expected is None:
            self.expected = (counter + 1) % COUNTER_MODULUS
            return Observation.FIRST
        ahead = (counter - expected) % COUNTER_MODULUS
        if ahead < _HALF:
            self.skipped += ahead
            self.last_gap = ahead
            missing = self._missing
            for k in range(max(0, ahead - _MISSING_WINDOW), ahead):
                missing[(expected + k) % COUNTER_MODULUS] = None
            while len(missing) > _MISSING_WINDOW:
                del missing[next(iter(missing))]
            self.expected = (counter + 1) % COUNTER_MODULUS
            return Observation.GAP
        if counter in self._missing:
            del self._missing[counter]
            self.late += 1
            return Observation.LATE
        self.duplicates += 1
        return Observation.DUPLICATE

    def reset(self) -> None:
        """Forget the sequence (e.g. after a reconnect, when the board may have restarted)."""
        self.expected = None
        self._missing.clear()
