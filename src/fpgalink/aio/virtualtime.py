"""An asyncio event loop on emulated time: whenever nothing is ready, its clock jumps to the
next timer instead of sleeping until it.

Everything the library does is timed by its loop's clock (``loop.time()``: timeouts, the
heartbeat, the deadman, telemetry staleness), and an in-process emulated board (``emu://``)
is paced by that same clock. On this loop a robot, its boards and the host therefore run
together as fast as the machine computes them, and exactly as they would on the wall clock
with an infinitely fast machine: the emulator never falls behind, no timer is ever late, and
a run does not depend on the machine's speed or load. Campaigns
(:mod:`fpgalink.campaign`) run their scenarios on it.

Only for hosts whose every far end is in this process: a real port's bytes arrive on the
wall clock, which this loop does not follow. Threads may hand results back
(``run_in_executor``, ``call_soon_threadsafe``), but the loop waits for them on the wall
clock only while no timer is pending: with one pending, emulated time runs on to it at
once, so a timeout around a thread's work expires in emulated time, whatever the thread
takes (campaigns run no threads).
"""

from __future__ import annotations

import asyncio
import selectors
from collections.abc import Coroutine
from typing import Any, TypeVar

__all__ = ["NothingScheduled", "VirtualTimeLoop", "run_virtual"]

T = TypeVar("T")

#: How long the loop waits on the wall clock for a thread's result when no timer is due: a
#: loop with nothing scheduled and nothing coming would otherwise wait for ever.
IDLE_WAIT_S = 30.0


class NothingScheduled(RuntimeError):
    """The loop had no timer, no ready callback and no thread's result arriving within
    :data:`IDLE_WAIT_S`: on emulated time nothing can happen any more (a task waits for an
    event without a timeout that nothing will set)."""


class _VirtualSelector(selectors.DefaultSelector):
    """The platform's selector, asked without waiting; a wait becomes a jump of the clock."""

    def __init__(self) -> None:
        super().__init__()
        self.now = 0.0

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        ready: list[tuple[selectors.SelectorKey, int]] = super().select(0)
        if ready or timeout == 0:
            return ready
        if timeout is None:
            # Nothing timed: only a thread can still wake the loop (its self-pipe).
            ready = super().select(IDLE_WAIT_S)
            if not ready:
                raise NothingScheduled(
                    "nothing is scheduled on the emulated-time loop and nothing arrived "
                    f"for {IDLE_WAIT_S:.0f} s: a task waits for something that cannot come")
            return ready
        self.now += timeout
        return ready


class VirtualTimeLoop(asyncio.SelectorEventLoop):
    """A selector event loop whose :meth:`time` is emulated seconds from 0."""

    def __init__(self) -> None:
        self._virtual = _VirtualSelector()
        super().__init__(self._virtual)

    def time(self) -> float:
        return self._virtual.now


def run_virtual(main: Coroutine[Any, Any, T]) -> T:
    """``asyncio.run`` on a fresh :class:`VirtualTimeLoop`."""
    with asyncio.Runner(loop_factory=VirtualTimeLoop) as runner:
        return runner.run(main)
