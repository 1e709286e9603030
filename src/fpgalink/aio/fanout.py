"""Who a link hands what its connection reports to: telemetry subscriptions (plain, and
stamped with the time the link received each sample), listeners of every event, and
watchers and callbacks of the link's status events. None is ever waited for: a subscription
that falls behind drops its oldest item, counted in ``subscriber_drops``."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from typing import Generic, NamedTuple, TypeVar

from fpgalink.aio.subscription import Subscription
from fpgalink.connection import LinkStats
from fpgalink.protocol import Event, Telemetry

__all__ = ["Stamped", "Subscribers"]

S = TypeVar("S")


class Stamped(NamedTuple):
    """A telemetry sample and when the link received it (the loop's clock, seconds)."""

    at: float
    sample: Telemetry


class Subscribers(Generic[S]):
    """The consumers of one link; ``S`` is the type of its status events."""

    def __init__(self, stats: LinkStats) -> None:
        self.closed = False
        self._stats = stats
        self._telemetry: set[Subscription[Telemetry]] = set()
        self._stamped: set[Subscription[Stamped]] = set()
        self._watchers: set[Subscription[S]] = set()
        self._listeners: list[Callable[[Event], None]] = []
        self._callbacks: list[Callable[[S], None]] = []

    @property
    def stamping(self) -> bool:
        """Some subscription wants the receive time."""
        return bool(self._stamped)

    def telemetry(self, maxsize: int) -> Subscription[Telemetry]:
        return self._subscribe(self._telemetry, maxsize)

    def stamped(self, maxsize: int) -> Subscription[Stamped]:
        return self._subscribe(self._stamped, maxsize)

    def watch(self, maxsize: int) -> AsyncIterator[S]:
        return self._subscribe(self._watchers, maxsize)

    def on_event(self, callback: Callable[[S], None]) -> Callable[[], None]:
        return _add(self._callbacks, callback)

    def add_listener(self, listener: Callable[[Event], None]) -> Callable[[], None]:
        return _add(self._listeners, listener)

    def deliver(self, event: Event, now: float) -> None:
        """``event`` to every listener; a sample to every telemetry subscription (stamped
        with ``now``)."""
        for listener in self._listeners:
            listener(event)
        if type(event) is Telemetry:
            stats = self._stats
            for sub in self._telemetry:
                if sub.put(event):
                    stats.subscriber_drops += 1
            for stamped in self._stamped:
                if stamped.put(Stamped(now, event)):
                    stats.subscriber_drops += 1

    def status(self, event: S) -> None:
        """A status event to every callback, at once, then to every watcher."""
        for callback in list(self._callbacks):
            callback(event)
        for watcher in self._watchers:
            watcher.put(event)

    def end(self) -> None:
        """The link closed: every subscription ends (a new one ends at once)."""
        self.closed = True
        _finish(self._telemetry)
        _finish(self._stamped)
        _finish(self._watchers)

    def _subscribe(self, subs: set[Subscription[T]], maxsize: int) -> Subscription[T]:
        sub: Subscription[T] = Subscription(maxsize, subs.discard)
        if self.closed:
            sub.finish()
        else:
            subs.add(sub)
        return sub


T = TypeVar("T")
C = TypeVar("C")


def _finish(subs: set[Subscription[T]]) -> None:
    for sub in subs:
        sub.finish()
    subs.clear()


def _add(callbacks: list[C], callback: C) -> Callable[[], None]:
    callbacks.append(callback)

    def remove() -> None:
        if callback in callbacks:
            callbacks.remove(callback)

    return remove
