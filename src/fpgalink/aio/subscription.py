"""Bounded subscriptions: the link (or the robot) puts, a consumer iterates, and neither ever
waits for the other."""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable
from typing import Generic, TypeVar

__all__ = ["Subscription"]

T = TypeVar("T")


class Subscription(Generic[T]):
    """``async for item in sub`` over a bounded queue that drops its oldest item when full
    (counting the drop) and ends when its producer finishes it or :meth:`close` is called.
    The producer never waits for a subscriber."""

    def __init__(self, maxsize: int, on_close: Callable[[Subscription[T]], None]) -> None:
        if maxsize < 1:
            raise ValueError("maxsize must be at least 1")
        self._items: deque[T] = deque(maxlen=maxsize)
        #: consumers waiting for an item, each on a future of its own (one cancelled
        #: consumer leaves the others waiting), made on the loop the first one ran on:
        #: asyncio.Event asks for the running loop at every wait, a system call (getpid) for
        #: every sample a follower waits for
        self._waiters: list[asyncio.Future[None]] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._closed = False
        self._on_close = on_close
        self.dropped = 0

    # --- the producer's side --------------------------------------------------------------

    def put(self, item: T) -> bool:
        """Queue ``item``; ``True`` when the oldest had to go to make room."""
        dropped = len(self._items) == self._items.maxlen
        if dropped:
            self.dropped += 1
        self._items.append(item)
        if self._waiters:
            self._wake()
        return dropped

    def finish(self) -> None:
        """No more items: iteration ends once the queued ones are read."""
        self._closed = True
        self._wake()

    def _wake(self) -> None:
        waiters, self._waiters = self._waiters, []
        for waiter in waiters:
            if not waiter.done():
                waiter.set_result(None)

    # --- the consumer's side --------------------------------------------------------------

    def close(self) -> None:
        self._on_close(self)
        self.finish()

    def __aiter__(self) -> Subscription[T]:
        return self

    async def __anext__(self) -> T:
        while not self._items:
            if self._closed:
                raise StopAsyncIteration
            loop = self._loop
            if loop is None:
                loop = self._loop = asyncio.get_running_loop()
            waiter: asyncio.Future[None] = loop.create_future()
            self._waiters.append(waiter)
            try:
                await waiter
            finally:
                # Woken, it is gone from the list (put took the list); cancelled, it leaves.
                if waiter in self._waiters:
                    self._waiters.remove(waiter)
        return self._items.popleft()

    @property
    def waiting(self) -> int:
        """Consumers waiting for an item now."""
        return len(self._waiters)

    def __len__(self) -> int:
        return len(self._items)

    async def __aenter__(self) -> Subscription[T]:
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()
