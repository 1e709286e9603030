"""The timer peripheral: an interrupt every ``TsTimerPeriod`` ms.

A new period takes effect from the next tick (the running count is not cut short), as when
the processor rewrites a timer's reload register.
"""

from __future__ import annotations

from collections.abc import Callable

from fpgaemu.timeline import EventHandle, Timeline, ms

__all__ = ["Timer"]


class Timer:
    def __init__(self, timeline: Timeline, period_ms: int = 1) -> None:
        self._timeline = timeline
        self.period_cycles = self._cycles(period_ms)
        self.next_tick: int | None = None
        self.handle: EventHandle | None = None  #: the scheduled next interrupt
        self.ticks = 0
        self._handlers: list[Callable[[int], None]] = []

    @staticmethod
    def _cycles(period_ms: int) -> int:
        if not 1 <= period_ms <= 1000:
            raise ValueError(f"timer period must be 1..1000 ms, got {period_ms}")
        return ms(period_ms)

    def on_interrupt(self, handler: Callable[[int], None]) -> None:
        self._handlers.append(handler)

    def set_period_ms(self, period_ms: int) -> None:
        self.period_cycles = self._cycles(period_ms)

    def start(self, now: int) -> None:
        """Start counting: the first interrupt comes one period after ``now``."""
        self.next_tick = now + self.period_cycles
        self.handle = self._timeline.schedule(self.next_tick, self._fire)

    def _fire(self, cycle: int) -> None:
        self.ticks += 1
        for handler in self._handlers:
            handler(cycle)
        # Reloaded after the handlers: a period written during this interrupt counts from
        # this tick on.
        self.next_tick = cycle + self.period_cycles
        self.handle = self._timeline.schedule(self.next_tick, self._fire)
