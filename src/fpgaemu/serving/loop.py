"""The event loop serve runs on, and what wakes the boards in it: :class:`Pacer` runs a
board's work at its deadlines and when host bytes arrive, never on a fixed beat;
:func:`serve_loop` is epoll with timers met to the microsecond; :func:`say` is serve's one
way to tell the user something on stderr."""

from __future__ import annotations

import asyncio
import contextlib
import select
import selectors
import sys
from collections.abc import Callable

__all__ = ["FD_SETSIZE", "MAX_SLEEP_S", "Pacer", "PreciseEpollSelector", "say", "serve_loop"]

#: The longest the serving loop sleeps without a deadline (a safety net, not a tick).
MAX_SLEEP_S = 1.0


class Pacer:
    """Runs ``tick()`` (advance the board, hand out its bytes) whenever the board has a
    deadline, and when :meth:`poke` says host bytes arrived — never on a fixed beat."""

    def __init__(self, tick: Callable[[], None], next_wake: Callable[[], float | None]
                 ) -> None:
        self._tick = tick
        self._next_wake = next_wake
        self._timer: asyncio.TimerHandle | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self.wakeups = 0

    def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._wake()

    def poke(self) -> None:
        """Something changed (host bytes arrived): the next deadline may be sooner."""
        if self._loop is not None:
            self._arm()

    def _wake(self) -> None:
        self._timer = None
        self.wakeups += 1
        self._tick()
        self._arm()

    def _arm(self) -> None:
        loop = self._loop
        assert loop is not None
        at = self._next_wake()
        now = loop.time()
        at = now + MAX_SLEEP_S if at is None else min(at, now + MAX_SLEEP_S)
        if self._timer is not None:
            if self._timer.when() <= at:
                return
            self._timer.cancel()
        self._timer = loop.call_at(at, self._wake)

    async def stop(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._loop = None





class PreciseEpollSelector(selectors.EpollSelector):
    """epoll — any number of descriptors, at any number — with timers met to the
    microsecond. ``epoll_wait`` takes whole milliseconds and rounds a wait up, which would put
    every reply up to a millisecond late; so a wait with a timeout is spent in ``select()``
    on the epoll descriptor itself (readable when any watched descriptor is ready, and
    ``select``'s timeout is in microseconds), then epoll is asked, without waiting, which.
    (When the epoll descriptor itself is above ``select``'s limit of 1024 the wait is
    epoll's own, to the millisecond.)"""

    def __init__(self) -> None:
        super().__init__()
        self._precise = self.fileno() < FD_SETSIZE

    def select(self, timeout: float | None = None
               ) -> list[tuple[selectors.SelectorKey, int]]:
        if self._precise and timeout is not None and timeout > 0:
            with contextlib.suppress(InterruptedError):
                select.select([self.fileno()], [], [], timeout)
            timeout = 0
        return super().select(timeout)


#: ``select()``'s limit: descriptors at or above it cannot be watched with it.
FD_SETSIZE = 1024


def serve_loop() -> asyncio.AbstractEventLoop:
    """The event loop ``fpgaemu serve`` runs on: the platform's default selector (epoll on
    Linux, as :class:`PreciseEpollSelector`), so no number of connections is too many for
    it."""
    default: type[selectors.BaseSelector] = selectors.DefaultSelector
    if default is selectors.EpollSelector:
        return asyncio.SelectorEventLoop(PreciseEpollSelector())
    return asyncio.SelectorEventLoop(default())


def say(text: str, *, once: str | None = None) -> None:
    """One line ``fpgaemu: TEXT`` on stderr; with ``once``, only the first time that key is
    said in this process."""
    if once is not None:
        if once in _SAID:
            return
        _SAID.add(once)
    print(f"fpgaemu: {text}", file=sys.stderr, flush=True)


_SAID: set[str] = set()

