"""The hosts in this process whose board is paced here (``emu://``): their own deadlines
belong to the far end's time.

A process starved as a whole (not scheduled for a while) starves both: when it runs again,
its board would catch up to the clock before its host's overdue timer ran, and the host's
heartbeat, due long before the board's watchdog, would reach the board after it. So the
board is not run past the earliest deadline a host of it has not yet met
(:meth:`HostDeadlines.overdue`), and the far end's lag (``FAR_END_LAG_EXTRA``) counts from
it: the host handles its timer at the time it was due, and what it writes then enters the
line then. Host and board catch up together, in the order things were due, as if the
process had never stopped.

A host whose deadline stays overdue although it had time to meet it (``HOST_WAIT_MAX_S``
of the clock) is not waited for any longer: a host stuck on a deadline it never clears must
not freeze its board.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable

__all__ = ["HOST_LATE_S", "HOST_TURN_S", "HOST_WAIT_MAX_S", "HostDeadlines"]

#: A host deadline is waited for once it is this far past: a timer a loop turn late (an
#: event loop arms none closer than half a millisecond) is not a process that stalled, and
#: the board's time is not held back for it (a campaign's figures do not move).
HOST_LATE_S = 0.005

#: While the board waits for its host's overdue deadline, the far end looks again this
#: soon (the host meets it in its own timer, a loop turn or two away).
HOST_TURN_S = 0.001
#: An overdue host deadline unchanged for this long on the clock is not waited for.
HOST_WAIT_MAX_S = 0.05


class HostDeadlines:
    """The next deadline of each host attached to one far end (a board, or a robot's
    boards), on the far end's time scale, the clock it is paced to."""

    __slots__ = ("_clock", "_dues", "_waited")

    def __init__(self, clock: Callable[[], float]) -> None:
        self._clock = clock
        self._dues: dict[Hashable, Callable[[], float | None]] = {}
        #: the overdue deadline waited for, and since when on the clock
        self._waited: tuple[float, float] | None = None

    def follow(self, host: Hashable, due: Callable[[], float | None]) -> None:
        """``due()``: when ``host`` next has work of its own (``None``: nothing scheduled)."""
        self._dues[host] = due

    def forget(self, host: Hashable) -> None:
        self._dues.pop(host, None)

    def overdue(self, now: float | None = None) -> float | None:
        """The earliest deadline of a host that has passed by more than ``HOST_LATE_S`` (at
        ``now``, default the clock's present) and not been met: the far end's time goes no
        further until it is (or until it has waited ``HOST_WAIT_MAX_S``)."""
        if not self._dues:
            return None
        now = self._clock() if now is None else now
        earliest: float | None = None
        for due in self._dues.values():
            at = due()
            if at is not None and at < now - HOST_LATE_S and (earliest is None
                                                              or at < earliest):
                earliest = at
        if earliest is None:
            self._waited = None
            return None
        waited = self._waited
        if waited is None or waited[0] != earliest:
            self._waited = (earliest, now)
        elif now - waited[1] > HOST_WAIT_MAX_S:
            return None
        return earliest

    def trailing(self, now: float) -> float:
        """How far the far end's time trails ``now`` for a host deadline it waits for (0:
        none)."""
        held = self.overdue(now)
        return 0.0 if held is None else now - held

    def allow(self, target: int, cycle_of: Callable[[float], int]) -> int:
        """``target`` (a cycle), or the cycle of the deadline waited for if sooner."""
        held = self.overdue()
        return target if held is None else min(target, cycle_of(held))
