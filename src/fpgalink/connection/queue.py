"""The connection's one event queue, in stream order, with its cap: a caller that never
drains it loses the oldest events, said by :class:`~fpgalink.events.EventsDropped` and
counted, never memory without bound."""

from __future__ import annotations

from collections import deque

from fpgalink.connection.stats import LinkStats
from fpgalink.events import (
    BoardBack,
    BoardFound,
    BoardRestarted,
    BoardResynced,
    BoardSilent,
    EventsDropped,
    RequestDone,
    RequestFailed,
    TelemetryResumed,
    TelemetryStale,
    WatchdogLapsed,
)
from fpgalink.protocol import Event

__all__ = ["EventQueue"]

#: Events that are never dropped when the queue overflows: they settle requests or liveness.
_KEEP_ON_OVERFLOW = (RequestDone, RequestFailed, BoardFound, BoardSilent, BoardRestarted,
                     BoardResynced, BoardBack, WatchdogLapsed, TelemetryStale,
                     TelemetryResumed)


class EventQueue(deque[Event]):
    """A deque of events; :meth:`trim` holds it to ``cap``."""

    def __init__(self, stats: LinkStats) -> None:
        super().__init__()
        self._stats = stats

    def trim(self, cap: int) -> None:
        """Drop the oldest events beyond ``cap`` but those that settle requests or
        liveness; say how many went."""
        excess = len(self) - cap
        if excess <= 0:
            return
        kept: list[Event] = []
        dropped = 0
        while dropped < excess and self:
            event = self.popleft()
            if isinstance(event, _KEEP_ON_OVERFLOW):
                kept.append(event)
            else:
                dropped += 1
        self.extendleft(reversed(kept))
        self._stats.events_dropped += dropped
        self.append(EventsDropped(dropped))
