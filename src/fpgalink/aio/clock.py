"""The link's clock: the time it passes to its connection, and the loop time at which a
deadline on it falls.

It is the loop's clock, except against a far end that runs in this process (an emulated
board) and says how far its time trails the loop's through its transport's
``get_extra_info(FAR_END_LAG_EXTRA)`` (:data:`~fpgalink.aio.transport.FAR_END_LAG_EXTRA`,
the transport contract): then the link's time is the far end's, so a process starved as a
whole, its board with it, sees neither stopped telemetry nor a lapsed heartbeat that the
board itself never saw. Such a far end may also ask when the link's own next deadline falls
(:data:`~fpgalink.aio.transport.HOST_DUE_EXTRA`): it then waits for the link to meet it, so
after a stall the link's heartbeat goes out at the time it was due, before the board's
watchdog. It never goes back.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable

from fpgalink.aio.transport import FAR_END_LAG_EXTRA, HOST_DUE_EXTRA

__all__ = ["LinkClock", "LinkTimer"]

#: A timer armed against a far end that has fallen behind comes no sooner than this: the far
#: end runs on this loop and needs the turn to catch up.
_MIN_REARM_S = 0.0005
#: While the far end trails, a timer is looked at again within this, its lag measured anew.
_LAGGING_RECHECK_S = 0.002


class LinkClock:
    __slots__ = ("_lag", "_last", "_loop")

    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self._lag: Callable[[float], float] | None = None
        self._last = -math.inf

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    def follow(self, transport: asyncio.BaseTransport,
               due: Callable[[], float | None]) -> None:
        """Keep the time of ``transport``'s far end, if it offers it; and tell the far end
        when this link's next deadline (``due()``, on this clock) falls, if it asks."""
        lag = transport.get_extra_info(FAR_END_LAG_EXTRA)
        self._lag = lag if callable(lag) else None
        follow_host = transport.get_extra_info(HOST_DUE_EXTRA)
        if self._lag is not None and callable(follow_host):
            follow_host(due)

    @property
    def far_end_time(self) -> bool:
        """The time is the far end's own (an in-process board's)."""
        return self._lag is not None

    def now(self) -> float:
        assert self._loop is not None
        now = self._loop.time()
        if self._lag is not None:
            # One reading of the clock for both: a deadline the far end waits for is met at
            # exactly its time, not a few microseconds short of it.
            now -= self._lag(now)
        if now < self._last:
            return self._last
        self._last = now
        return now

    def loop_time(self, deadline: float) -> float:
        """When, on the loop's clock, to look at ``deadline`` (on this clock). Against a
        trailing far end the lag shrinks as it catches up, so the deadline then comes sooner
        than it looked: a timer comes early, finds nothing due and is armed again."""
        assert self._loop is not None
        if self._lag is None:
            return deadline
        now = self._loop.time()
        lag = now - self.now()
        at = max(deadline + lag, now + _MIN_REARM_S)
        if lag > _MIN_REARM_S:
            at = min(at, now + _LAGGING_RECHECK_S)
        return at


class LinkTimer:
    """The link's one timer, on its clock: armed for the connection's next deadline
    (:meth:`arm`), calling ``on_timer`` then. The deadline it is for (:meth:`due`) stays
    until it is armed again, after what the connection wrote on it went out: a far end in
    this process that waits for it keeps the link's time at it, and takes those bytes at
    it (:data:`~fpgalink.aio.transport.HOST_DUE_EXTRA`)."""

    __slots__ = ("_at", "_clock", "_handle", "_on_timer")

    def __init__(self, clock: LinkClock, on_timer: Callable[[], None]) -> None:
        self._clock = clock
        self._on_timer = on_timer
        self._handle: asyncio.TimerHandle | None = None
        self._at: float | None = None  #: on the link's clock

    def arm(self, loop: asyncio.AbstractEventLoop, deadline: float | None) -> None:
        if deadline is None:
            if self._handle is None:
                self._at = None
            return
        # Every message heard pushes the liveness deadline later; re-arming on each read
        # would churn the loop's timer heap at 1 kHz. A timer already due no later than the
        # new deadline stays: when it fires early, handle_timer finds nothing to do and it
        # is armed again for the real deadline.
        if self._handle is not None and self._at is not None and self._at <= deadline:
            return
        if self._handle is not None:
            self._handle.cancel()
        self._at = deadline
        self._handle = loop.call_at(self._clock.loop_time(deadline), self._fire)

    def due(self) -> float | None:
        """The deadline the link acts on next, on its clock (``None``: none)."""
        return self._at

    def cancel(self) -> None:
        if self._handle is not None:
            self._handle.cancel()
        self._handle = self._at = None

    def _fire(self) -> None:
        self._handle = None
        self._on_timer()
