"""A board's clock (``t_us``: a u32 of microseconds since power-up, wrapping every ~71.6
minutes) mapped onto a host clock, sans-I/O: the host time a sample arrived is passed in.

A stamp is the host time at which the board sampled, not the time the host read the
sample: a burst read at one instant keeps its true spacing. The mapping is estimated
continuously from every sample, not anchored once (an anchor carries the first sample's
delay, 51–105 ms in the CLI's first bags):

- A sample cannot arrive before it was taken, so ``arrival − board time`` is the offset
  plus a delay that is never negative; its lower envelope is the offset plus the smallest
  delay (the ``TM``'s own time on the wire, about 0.5 ms at 1 MBd). Each second of board
  time contributes one point, the minimum over that second.
- The board's crystal and the host's clock drift apart by their tolerances (tens of ppm,
  100 ppm is 0.36 s an hour). Once the points span :data:`DRIFT_SPAN_US` (10 s), a line is
  fitted through the last :data:`HISTORY` points (a minute) by least squares, points far
  above it (a second in which the host was stalled throughout) left out, and lowered to
  the lowest of them: its slope is the drift.
- Stamps stay in order: the offset in use follows the estimate at once upwards, and
  downwards (a smaller delay found, at the start in particular) by at most
  :data:`MAX_SLEW` of the board time that passed, so consecutive stamps are never closer
  than 75 % of their board spacing: a first delay of 80 ms is worked off in 0.32 s, and
  the 210 ms by which the in-process emulator's first sample comes late (its board
  powers up before the host has connected, then catches up) in 0.84 s. Once locked the
  corrections are microseconds, done in a sample or two.

A backward jump of less than half the counter is a board restart: the mapping starts
again from that sample (the drift estimate is kept: it is the same crystal); a larger
one is the counter's wrap."""

from __future__ import annotations

from collections import deque

__all__ = ["BOARD_CLOCK_WRAP_US", "DRIFT_SPAN_US", "HISTORY", "MAX_SLEW", "BoardClock"]

BOARD_CLOCK_WRAP_US = 1 << 32
#: Board time each envelope point covers.
WINDOW_US = 1_000_000
#: Envelope points kept (a minute at one a second).
HISTORY = 60
#: The drift is estimated once the points span this much board time (before: none).
DRIFT_SPAN_US = 10_000_000
#: Beyond this the board's crystal or the host's clock is broken: the drift is clamped.
MAX_DRIFT_PPM = 1000.0
#: How fast the offset in use may fall, as a share of the board time passed.
MAX_SLEW = 0.25
#: A point further than this above the fitted line is left out of the fit (ns).
OUTLIER_NS = 2_000_000


class BoardClock:
    """``ns(t_us, host_now_ns)`` for each sample in arrival order; the stamp it returns is
    the host time, integer nanoseconds, at which the board took the sample."""

    __slots__ = ("_anchor_ns", "_applied", "_applied_u", "_base_us", "_last_us", "_line",
                 "_origin_us", "_points", "_slope", "_win_min", "_win_start", "_win_u",
                 "anchors")

    def __init__(self) -> None:
        self._last_us: int | None = None
        self._base_us = 0  #: wraps so far, in µs
        self._origin_us = 0  #: the raw t_us the unwrapped board time counts from
        #: the host time of the first sample since the last anchor: offsets are kept
        #: relative to it, small numbers a float holds to the nanosecond
        self._anchor_ns = 0
        self._points: deque[tuple[int, int]] = deque(maxlen=HISTORY)
        self._win_start = 0
        self._win_u = 0
        self._win_min = 0
        #: the estimate: offset (ns) = intercept + slope × board µs
        self._line: tuple[float, float] | None = None
        self._slope = 0.0  #: ns per board µs: −0.1 for a board 100 ppm fast
        self._applied = 0.0  #: the offset in use (ns), and the board time it was used at
        self._applied_u = 0
        self.anchors = 0  #: times the mapping started afresh (first sample, restarts)

    @property
    def anchored(self) -> bool:
        return self._last_us is not None

    @property
    def drift_ppm(self) -> float:
        """How much faster the board's clock runs than the host's, ppm (0 until the
        samples span :data:`DRIFT_SPAN_US`)."""
        return -self._slope / (1000.0 + self._slope) * 1e6

    @property
    def offset_ns(self) -> float:
        """The offset in use: host ns minus board ns (counted from the anchor sample) at
        the last sample."""
        return self._anchor_ns + self._applied

    def ns(self, t_us: int, host_now_ns: int) -> int:
        """The host time, integer nanoseconds, at which the board sampled ``t_us``;
        ``host_now_ns``: when the sample arrived, on the host clock."""
        last, self._last_us = self._last_us, t_us
        if last is None or (t_us < last and last - t_us < BOARD_CLOCK_WRAP_US // 2):
            self._anchor(t_us, host_now_ns)
            return host_now_ns
        if t_us < last:
            self._base_us += BOARD_CLOCK_WRAP_US
        u = self._base_us + t_us - self._origin_us
        lowest = host_now_ns - self._anchor_ns - 1000 * u  # offset + this sample's delay
        if u - self._win_start >= WINDOW_US:
            self._points.append((self._win_u, self._win_min))
            self._fit()
            self._win_start, self._win_u, self._win_min = u, u, lowest
        elif lowest < self._win_min:
            self._win_u, self._win_min = u, lowest
        target = self._win_min + self._slope * (u - self._win_u)
        if self._line is not None:
            target = min(target, self._line[0] + self._line[1] * u)
        floor = self._applied - MAX_SLEW * 1000 * (u - self._applied_u)
        self._applied, self._applied_u = max(target, floor), u
        return self._anchor_ns + 1000 * u + round(self._applied)

    def restart(self) -> None:
        """The board restarted (said by its link): the next sample starts the mapping
        afresh, whatever its ``t_us``; the drift estimate is kept (the same crystal)."""
        self._last_us = None

    def seconds(self, t_us: int, host_now: float) -> float:
        """As :meth:`ns`, in float seconds."""
        return self.ns(t_us, round(host_now * 1e9)) / 1e9

    def _anchor(self, t_us: int, host_now_ns: int) -> None:
        self.anchors += 1
        self._origin_us, self._base_us = t_us, 0
        self._points.clear()
        self._line = None
        self._anchor_ns = host_now_ns
        self._win_start = self._win_u = self._win_min = 0
        self._applied, self._applied_u = 0.0, 0

    def _fit(self) -> None:
        """The envelope line through the points: least squares for the slope once they
        span long enough (points far above left out), then lowered to the lowest."""
        points = list(self._points)
        slope = self._slope
        if points[-1][0] - points[0][0] >= DRIFT_SPAN_US:
            kept = points
            for _ in range(2):
                fitted = _least_squares(kept)
                if fitted is None:
                    break
                _, slope = fitted
                low = min(y - slope * x for x, y in kept)
                kept = [(x, y) for x, y in kept if y - slope * x - low <= OUTLIER_NS]
            limit = MAX_DRIFT_PPM * 1e-3  # ns per µs
            slope = max(-limit, min(limit, slope))
        self._slope = slope
        self._line = (min(y - slope * x for x, y in points), slope)


def _least_squares(points: list[tuple[int, int]]) -> tuple[float, float] | None:
    n = len(points)
    if n < 2:
        return None
    mean_x = sum(x for x, _ in points) / n
    mean_y = sum(y for _, y in points) / n
    sxx = sum((x - mean_x) ** 2 for x, _ in points)
    if sxx == 0:
        return None
    slope = sum((x - mean_x) * (y - mean_y) for x, y in points) / sxx
    return mean_y - slope * mean_x, slope
