"""Message counters (SPEC §4): the sender's wrapping counter and the receiver's tracker that
turns the counters it sees into lost / duplicated / reordered counts."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import Final

from fpgalink.protocol.messages import COUNTER_MODULUS

__all__ = ["CounterTracker", "Observation", "SendCounter"]

#: How far back a counter is still "recent": older ones are judged duplicates of something
#: long gone. Half the counter space, so the wrap never looks like a jump backwards.
_HALF: Final = COUNTER_MODULUS // 2
#: How far behind the expected counter a missing one is still remembered, so its late
#: arrival is recognised as reordering rather than a duplicate.
_MISSING_WINDOW: Final = 4096
#: A jump ahead by more than this is only believed once the next counter follows it: a
#: single corrupted counter (there is no checksum) must not make every later message look
#: old. At 1 kHz this is a one-second outage.
_TRUSTED_JUMP: Final = 1000


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
    a late arrival if it was one of the skipped within the last :data:`_MISSING_WINDOW`
    counters, else a duplicate. ``lost`` is the net.

    Every counter sequence costs O(1) per message: missing counters are marked in a table
    indexed by counter value (a C-level fill per gap, at most the window long), tagged with
    the lap of the counter space they belong to, so nothing has to be trimmed one entry at a
    time and marks older than the window simply stop matching."""

    expected: int | None = None
    received: int = 0
    skipped: int = 0  #: counters jumped over (each counted once, when the jump is seen)
    late: int = 0  #: skipped counters that arrived afterwards (reordering)
    duplicates: int = 0
    corrupted: int = 0  #: counters judged damaged (a big jump the next counter denied)
    last_gap: int = 0
    suspect: int | None = None
    laps: int = 0  #: times the expected counter passed 99999 → 0
    _held: int = 0  #: the expected counter while a suspect is pending
    #: per counter value: 0, or 1 + the lap (mod 255) in which it went missing
    _missing: bytearray = field(default_factory=lambda: bytearray(COUNTER_MODULUS), repr=False)

    @property
    def lost(self) -> int:
        """Messages skipped and not (yet) seen: the net loss."""
        return self.skipped - self.late

    def _expect_after(self, counter: int) -> None:
        """The next counter expected is the one after ``counter``, which is ahead of (or at)
        the present expectation; count the lap when that passes 99999."""
        following = counter + 1 if counter != COUNTER_MODULUS - 1 else 0
        previous = self.expected
        # Moving forward by less than half the space, a smaller value means the wrap.
        if previous is not None and previous >= 0 and following < previous:
            self.laps += 1
        self.expected = following

    def observe_in_order(self, first: int, n: int = 1) -> bool:
        """The ``n`` counters ``first``, ``first + 1``, … (the caller has checked they run
        so) when ``first`` is the one expected and the run stops short of the wrap: counted
        as ``n`` :meth:`observe` calls would count them (each ``IN_ORDER``), and True. Else
        nothing is counted and False: observe them one by one. The 1 kHz telemetry case,
        without a call per message."""
        if self.expected != first or first + n >= COUNTER_MODULUS:
            return False
        self.expected = first + n
        self.received += n
        return True

    def observe(self, counter: int) -> Observation:
        self.received += 1
        expected = self.expected
        if expected == counter:
            self._expect_after(counter)
            return Observation.IN_ORDER
        if expected is None:
            self.expected = counter + 1 if counter != COUNTER_MODULUS - 1 else 0
            return Observation.FIRST
        suspect = self.suspect
        if suspect is not None:
            expected = self._held
            self.expected = expected
            self.suspect = None
            if 0 < (counter - suspect) % COUNTER_MODULUS <= _TRUSTED_JUMP:
                # The jump is real (an outage, a board restart): count it from the suspect.
                self._expect_after(counter)
                self._gap(expected, (suspect - expected) % COUNTER_MODULUS)
                self._gap((suspect + 1) % COUNTER_MODULUS,
                          (counter - suspect - 1) % COUNTER_MODULUS)
                self.last_gap = (counter - expected) % COUNTER_MODULUS - 1
                return Observation.GAP
            self.corrupted += 1
            ahead = (counter - expected) % COUNTER_MODULUS
            if ahead <= 1:
                # Back on the expected sequence: the suspect was the expected message with a
                # damaged counter (ahead 1), or a damaged extra (ahead 0). Nothing was lost.
                self._expect_after(counter)
                return Observation.CORRUPT
        ahead = (counter - expected) % COUNTER_MODULUS
        if _TRUSTED_JUMP < ahead < _HALF:
            self.suspect = counter
            self._held = expected
            # Until the next counter decides, nothing may match as "in order".
            self.expected = -1
            return Observation.SUSPECT
        if ahead < _HALF:
            self._expect_after(counter)
            self._gap(expected, ahead)
            self.last_gap = ahead
            return Observation.GAP
        if self._take_missing(counter):
            self.late += 1
            return Observation.LATE
        self.duplicates += 1
        return Observation.DUPLICATE

    def _tag(self, counter: int) -> int:
        """The mark of ``counter`` as a counter behind the present expectation."""
        expected = self.expected
        assert expected is not None and expected >= 0
        lap = self.laps if counter < expected else self.laps - 1
        return lap % 255 + 1

    def _gap(self, first: int, count: int) -> None:
        """``count`` counters from ``first`` on were skipped (all behind the expectation)."""
        self.skipped += count
        remembered = min(count, _MISSING_WINDOW)
        start = (first + count - remembered) % COUNTER_MODULUS
        missing = self._missing
        while remembered:
            run = min(remembered, COUNTER_MODULUS - start)
            missing[start : start + run] = bytes((self._tag(start),)) * run
            remembered -= run
            start = 0

    def _take_missing(self, counter: int) -> bool:
        """Whether ``counter`` went missing within the window (and is no longer missing)."""
        expected = self.expected
        if expected is None or expected < 0:
            return False
        behind = (expected - counter) % COUNTER_MODULUS
        if not 0 < behind <= _MISSING_WINDOW or self._missing[counter] != self._tag(counter):
            return False
        self._missing[counter] = 0
        return True

    def reset(self) -> None:
        """Forget the sequence (e.g. after a reconnect, when the board may have restarted)."""
        self.expected = None
        self.suspect = None
        self._held = 0
        self._missing[:] = bytes(COUNTER_MODULUS)
