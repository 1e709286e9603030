"""The robot's timers on its event loop: the supervisor's deadman and the command arbiter's
(timeouts, the enable's renewal), each armed at the deadline its sans-I/O part gives."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

__all__ = ["LoopTimers"]


class LoopTimers:
    """Named one-shot timers; nothing is armed before :meth:`start` or after
    :meth:`close`."""

    def __init__(self) -> None:
        self.loop: asyncio.AbstractEventLoop | None = None
        self._handles: dict[str, asyncio.TimerHandle] = {}
        self._graced: set[str] = set()

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop

    def now(self) -> float:
        return (self.loop or asyncio.get_running_loop()).time()

    def arm(self, name: str, deadline: float | None, callback: Callable[[], None]) -> None:
        """``callback`` by ``deadline`` (the loop's clock; ``None``: none due). A timer
        already armed no later stays: it fires first, and its callback (which calls
        :meth:`fired`, then arms the next) finds what is due then. (Re-armed at every
        command, a timer whose deadline had passed was cancelled from the ready queue by
        the next command of a flood before it could run, again and again: the enable's
        renewal starved and the deadman lapsed.)"""
        if self.loop is None:
            return
        armed = self._handles.get(name)
        if armed is not None and not armed.cancelled():
            if deadline is None or armed.when() <= deadline:
                return
            armed.cancel()
        if deadline is not None:
            self._handles[name] = self.loop.call_at(deadline, callback)

    def fired(self, name: str) -> None:
        handle = self._handles.pop(name, None)
        if handle is not None:
            handle.cancel()

    def grace(self, name: str, deadline: float | None, late_after: float, grace: float,
              callback: Callable[[], None]) -> bool:
        """Whether ``name``'s timer, firing now for ``deadline``, was so late (more than
        ``late_after`` s: this loop was not running, a blocked or starved process) that it
        is given ``grace`` s of running time first (once; ``callback`` again then)."""
        late = deadline is not None and self.now() - deadline > late_after
        if late and name not in self._graced and self.loop is not None:
            self._graced.add(name)
            self._handles[name] = self.loop.call_later(grace, callback)
            return True
        self._graced.discard(name)
        return False

    def close(self) -> None:
        for handle in self._handles.values():
            handle.cancel()
        self._handles.clear()
        self.loop = None
