"""Message counters (SPEC §4): the sender's wrapping counter and the receiver's tracker that
turns the counters it sees into lost / duplicated / reordered counts."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from fpgalink.protocol.messages import COUNTER_MODULUS

__all__ = ["CounterTracker", "Observation", "SendCounter"]

#: How far back a counter is still "recent": older ones are judged duplicates of something
#: long gone. Half the counter space, so the wrap never looks like a jump backwards.
_HALF = COUNTER_MODULUS // 2
#: How many missing counters are remembered, so a late arrival is recognised as reordered.
_MISSING_WINDOW = 4096
#: A jump ahead by more than this is only believed once the next counter follows it: a
#: single corrupted counter (there is no checksum) must not make every later message look
#: old. At 1 kHz this is a one-second outage.
_TRUSTED_JUMP = 1000


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
    SUSPECT = "suspect"  #: a jump too large to believe yet; the next counter decides
    CORRUPT = "corrupt"  #: the last suspect was a damaged counter, not a jump


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
    corrupted: int = 0  #: counters judged damaged (a big jump the next counter denied)
    last_gap: int = 0
    suspect: int | None = None
    _held: int = 0  #: the expected counter while a suspect is pending
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
        suspect = self.suspect
        if suspect is not None:
            expected = self._held
            self.suspect = None
            if 0 < (counter - suspect) % COUNTER_MODULUS <= _TRUSTED_JUMP:
                # The jump is real (an outage, a board restart): count it from the suspect.
                self._gap(expected, (suspect - expected) % COUNTER_MODULUS)
                self._gap((suspect + 1) % COUNTER_MODULUS,
                          (counter - suspect - 1) % COUNTER_MODULUS)
                self.last_gap = (counter - expected) % COUNTER_MODULUS - 1
                self.expected = (counter + 1) % COUNTER_MODULUS
                return Observation.GAP
            self.corrupted += 1
            ahead = (counter - expected) % COUNTER_MODULUS
            if ahead <= 1:
                # Back on the expected sequence: the suspect was the expected message with a
                # damaged counter (ahead 1), or a damaged extra (ahead 0). Nothing was lost.
                self.expected = (counter + 1) % COUNTER_MODULUS
                return Observation.CORRUPT
            self.expected = expected
        ahead = (counter - expected) % COUNTER_MODULUS
        if _TRUSTED_JUMP < ahead < _HALF:
            self.suspect = counter
            self._held = expected
            # Until the next counter decides, nothing may match as "in order".
            self.expected = -1
            return Observation.SUSPECT
        if ahead < _HALF:
            self._gap(expected, ahead)
            self.last_gap = ahead
            self.expected = (counter + 1) % COUNTER_MODULUS
            return Observation.GAP
        if counter in self._missing:
            del self._missing[counter]
            self.late += 1
            return Observation.LATE
        self.duplicates += 1
        return Observation.DUPLICATE

    def _gap(self, first: int, count: int) -> None:
        """``count`` counters from ``first`` on were skipped."""
        self.skipped += count
        missing = self._missing
        for k in range(max(0, count - _MISSING_WINDOW), count):
            missing[(first + k) % COUNTER_MODULUS] = None
        while len(missing) > _MISSING_WINDOW:
            del missing[next(iter(missing))]

    def reset(self) -> None:
        """Forget the sequence (e.g. after a reconnect, when the board may have restarted)."""
        self.expected = None
        self.suspect = None
        self._held = 0
        self._missing.clear()
