"""The connection's one event queue, in stream order, with its cap: a caller that never
drains it loses the oldest events, said by :class:`~fpgalink.events.EventsDropped` and
counted, never memory without bound."""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

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


class EventQueue:
    """The events, oldest first; :meth:`trim` holds them to ``cap``. (A deque held, not
    subclassed: the compiled build's classes cannot derive from a built-in container.)"""

    __slots__ = ("_items", "_stats")

    def __init__(self, stats: LinkStats) -> None:
        self._items: deque[Event] = deque()
        self._stats = stats

    def append(self, event: Event) -> None:
        self._items.append(event)

    def extend(self, events: Iterable[Event]) -> None:
        self._items.extend(events)

    def popleft(self) -> Event:
        return self._items.popleft()

    def __len__(self) -> int:
        return len(self._items)

    def __bool__(self) -> bool:
        return bool(self._items)

    def trim(self, cap: int) -> None:
        """Drop the oldest events beyond ``cap`` but those that settle requests or
        liveness; say how many went."""
        items = self._items
        excess = len(items) - cap
        if excess <= 0:
            return
        kept: list[Event] = []
        dropped = 0
        while dropped < excess and items:
            event = items.popleft()
            if isinstance(event, _KEEP_ON_OVERFLOW):
                kept.append(event)
            else:
                dropped += 1
        items.extendleft(reversed(kept))
        self._stats.events_dropped += dropped
        items.append(EventsDropped(dropped))
