"""A board's clock (``t_us``: a u32 of microseconds since power-up, wrapping every ~71.6
minutes) mapped onto a host clock, sans-I/O: the host time is passed in.

Anchored to the host clock at the first sample, then advanced by board time alone, so
samples that arrive in one burst keep their true spacing and a stamp is the board's
sampling instant, not the host's reading instant (offset by the first sample's delay). A
backward jump of less than half the counter is a board restart (anchored again); more is a
wrap. The board's crystal and the host's clock drift apart by their tolerances (tens of
ppm: about 0.1 s in an hour); runs that matter for longer re-anchor by restarting."""

from __future__ import annotations

__all__ = ["BOARD_CLOCK_WRAP_US", "BoardClock"]

BOARD_CLOCK_WRAP_US = 1 << 32


class BoardClock:
    __slots__ = ("_anchor_ns", "_base_us", "_last_us", "_origin_us")

    def __init__(self) -> None:
        self._anchor_ns: int | None = None
        self._origin_us = 0
        self._last_us = 0
        self._base_us = 0

    @property
    def anchored(self) -> bool:
        return self._anchor_ns is not None

    def ns(self, t_us: int, host_now_ns: int) -> int:
        """The host time, integer nanoseconds, at which the board sampled ``t_us``;
        ``host_now_ns`` is now on the host clock (used to anchor)."""
        last, self._last_us = self._last_us, t_us
        if self._anchor_ns is None or (t_us < last and last - t_us < BOARD_CLOCK_WRAP_US // 2):
            self._anchor_ns = host_now_ns
            self._origin_us, self._base_us = t_us, 0
        elif t_us < last:
            self._base_us += BOARD_CLOCK_WRAP_US
        return self._anchor_ns + (self._base_us + t_us - self._origin_us) * 1000

    def seconds(self, t_us: int, host_now: float) -> float:
        """As :meth:`ns`, in float seconds."""
        return self.ns(t_us, round(host_now * 1e9)) / 1e9
