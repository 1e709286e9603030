"""The timer peripheral: an interrupt every ``TsTimerPeriod`` ms.

A new period takes effect from the next tick (the running count is not cut short), as when
the processor rewrites a timer's reload register.
"""

from __future__ import annotations

from fpgaemu.timeline import CLOCK_HZ

__all__ = ["Timer"]


class Timer:
    def __init__(self, period_ms: int = 1) -> None:
        self.period_cycles = self._cycles(period_ms)
        self.next_tick: int | None = None
        self.ticks = 0

    @staticmethod
    def _cycles(period_ms: int) -> int:
        if not 1 <= period_ms <= 1000:
            raise ValueError(f"timer period must be 1..1000 ms, got {period_ms}")
        return period_ms * CLOCK_HZ // 1000

    def set_period_ms(self, period_ms: int) -> None:
        self.period_cycles = self._cycles(period_ms)

    def start(self, now: int) -> int:
        self.next_tick = now + self.period_cycles
        return self.next_tick

    def tick(self, now: int) -> int:
        """Called at a tick; returns the cycle of the next one."""
        self.ticks += 1
        self.next_tick = now + self.period_cycles
        return self.next_tick
