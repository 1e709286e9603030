"""Liveness, both ways: this host keeping the board enabled (:class:`Heartbeat`, and the
judgement that the board's watchdog lapsed), the board heard or silent (:class:`Hearing`),
and its telemetry arriving as configured (:class:`TelemetryWatch`).

Each is told the time; each says what it found as an event through ``emit``, and a
heartbeat goes out through ``send``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from enum import Enum

from fpgalink.connection.settings import WATCHDOG_S, Settings
from fpgalink.connection.stats import LinkStats
from fpgalink.events import TelemetryResumed, TelemetryStale, WatchdogLapsed
from fpgalink.protocol import (
    COUNTER_MODULUS,
    DirectCommand,
    Disable,
    Enable,
    Event,
    Param,
    Telemetry,
    lookup,
)

__all__ = ["T_US_WRAP", "Hearing", "Heartbeat", "Liveness", "TelemetryWatch"]

_ENABLE, _DISABLE = Enable(), Disable()
T_US_WRAP = 1 << 32  #: the board's t_us is a u32 of microseconds
_WATCHDOG_US = round(WATCHDOG_S * 1e6)
#: The two parameters that say whether, and how often, the board sends telemetry.
_GET_DATA = lookup("GetDataPeriodical")
_PERIOD = lookup("TsTimerPeriod")
#: Before the telemetry period is known (confirmed or seen), a stream may wait this long for
#: its first samples: the longest period the board allows.
_LONGEST_PERIOD_S = 1.0
#: A gap between two of this host's ``RE`` is remembered this long: the board's samples
#: showing the lapse it caused arrive well within it, even on a loaded host.
_RECENT_GAP_S = 1.0


class Liveness(Enum):
    UNKNOWN = "unknown"  #: nothing heard since the port (re)opened
    ALIVE = "alive"
    LOST = "lost"  #: silent for longer than the liveness timeout, or the port is gone


class Heartbeat:
    """``RE`` every heartbeat interval while enabled; an overdue one is not sent (the board's
    watchdog has lapsed or is about to) and neither is the board left enabled by this host
    when its telemetry shows it disabled itself: ``RD`` and
    :class:`~fpgalink.events.WatchdogLapsed` instead."""

    def __init__(self, settings: Settings, stats: LinkStats, *,
                 send: Callable[[DirectCommand, float], None], emit: Callable[[Event], None],
                 port_up: Callable[[], bool]) -> None:
        self.settings = settings
        self.enabled = False  #: this host sends ``RE`` every heartbeat interval
        self.next_at: float | None = None
        self._last_at: float | None = None  #: when the last RE was queued
        #: the longest gap between two RE queued within :data:`_RECENT_GAP_S`, and when
        self._recent_gap = 0.0
        self._recent_gap_at = -math.inf
        self._enable_seen = False  #: the board's telemetry showed it enabled by this host
        self._saw_disabled = False  #: since enable(), a sample showed the board disabled
        self._enabled_since_us: int | None = None  #: since enable(), enabled from this t_us
        self._stats = stats
        self._send = send
        self._emit = emit
        self._port_up = port_up

    def enable(self, now: float) -> None:
        if not self.enabled:
            self._enable_seen = self._saw_disabled = False
            self._enabled_since_us = None
            self._last_at = None  # gaps count between this enable's RE only
            self._recent_gap, self._recent_gap_at = 0.0, -math.inf
        self.enabled = True
        self._beat(now)

    def disable(self, now: float) -> None:
        self.stop()
        if self._port_up():
            self._send(_DISABLE, now)

    def stop(self) -> None:
        """No more heartbeats, nothing sent (the port is gone: the board's watchdog lapses
        by itself)."""
        self.enabled = False
        self._enable_seen = False
        self.next_at = None

    def due(self, now: float) -> None:
        if self.next_at is None or now < self.next_at:
            return
        last = self._last_at
        if self.enabled and last is not None and now - last >= self.settings.heartbeat_give_up:
            # Overdue past the board's watchdog: the caller stalled. Supervision decides
            # what happens next, not a late RE.
            self.lapse(now, now - last, f"this host sent no RE for {now - last:.3f} s")
        else:
            self._beat(now)

    def lapse(self, now: float, host_silent_for: float | None, detail: str) -> None:
        """The board is (or is about to be) disabled by its watchdog while meant enabled:
        stop keeping it enabled, make it definite with ``RD``, and say so."""
        self.disable(now)
        self._stats.watchdog_lapses += 1
        self._emit(WatchdogLapsed(host_silent_for, detail, at=now))

    def board_restarted(self, now: float) -> None:
        if self.enabled:
            self.disable(now)
        self._enable_seen = False

    def watch(self, samples: Sequence[Telemetry], now: float) -> None:
        """The host keeps the board enabled. Once its telemetry has shown it enabled by this
        host's ``RE``, a sample showing it disabled means the board disabled itself.

        Shown enabled by this host: samples still on the way when ``enable()`` was called
        may show it enabled from before an ``RD`` (then disabled, then enabled): so it is a
        rise from disabled to enabled, or enabled samples spanning the watchdog's 300 ms of
        board time (no earlier enable outlives that without this host's ``RE``)."""
        if not self.enabled:
            return
        if self._enable_seen:
            for sample in samples:
                if not sample.a.flags & 1:
                    self._disabled_itself(now)
                    return
            return
        for index, sample in enumerate(samples):
            if not sample.a.flags & 1:
                self._saw_disabled = True
                self._enabled_since_us = None
            elif self._saw_disabled:
                self._enable_seen = True
            elif self._enabled_since_us is None:
                self._enabled_since_us = sample.t_us
            elif (sample.t_us - self._enabled_since_us) % T_US_WRAP >= _WATCHDOG_US:
                self._enable_seen = True
            if self._enable_seen:
                self.watch(samples[index + 1:], now)
                return

    def _disabled_itself(self, now: float) -> None:
        """The board's telemetry shows it disabled while this host kept sending ``RE``. When
        two of them went out twice the interval apart or more, this host's own lateness
        (its process not scheduled in time) used most of the watchdog's 300 ms, and is
        said as such: a host that was on time leaves the line or another sender's ``RD``."""
        late = self._recent_gap if now - self._recent_gap_at <= _RECENT_GAP_S else 0.0
        if late >= 2 * self.settings.heartbeat_interval:
            self.lapse(now, late, f"this host's RE went out {late:.3f} s apart, and its "
                       "telemetry shows it disabled")
        else:
            self.lapse(now, None, "its telemetry shows it disabled after it was enabled, "
                       "while this host kept sending RE: the RE came more than 300 ms "
                       "apart at the board, or an RD came from elsewhere")

    def _beat(self, now: float) -> None:
        if self._port_up():
            self._send(_ENABLE, now)
            self._stats.heartbeats_sent += 1
            last = self._last_at
            if last is not None and self.enabled:
                gap = now - last
                if gap >= self._recent_gap or now - self._recent_gap_at > _RECENT_GAP_S:
                    self._recent_gap, self._recent_gap_at = gap, now
            self._last_at = now
        self.next_at = now + self.settings.heartbeat_interval


class Hearing:
    """Whether the board is heard: any well-formed message counts; silent for the liveness
    timeout, it is lost."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.liveness = Liveness.UNKNOWN
        self._last_heard: float | None = None
        self._origin: float | None = None  #: silence counts from here before anything heard

    def start(self, now: float) -> None:
        """Begin expecting the board: silence from ``now`` on counts."""
        self._origin = now

    def heard(self, now: float) -> None:
        self._last_heard = now

    def deadline(self) -> float | None:
        if self.liveness is Liveness.LOST:
            return None
        origin = self.silent_since
        return None if origin is None else origin + self.settings.liveness_timeout

    @property
    def silent_since(self) -> float | None:
        return self._last_heard if self._last_heard is not None else self._origin

    def reconnected(self, now: float) -> None:
        """A new port: liveness is judged anew from ``now``."""
        self.liveness = Liveness.UNKNOWN
        self._last_heard = None
        self._origin = now


class TelemetryWatch:
    """The telemetry stream as the board's confirmed settings say it should be: configured on
    (``GetDataPeriodical`` = 1) and none for ``stale_periods`` periods is
    :class:`~fpgalink.events.TelemetryStale`; samples again, :class:`TelemetryResumed`.

    ``boards_time``: ``now`` is the board's own time (an emulated board in the caller's
    process, whose time trails the wall clock when the process is starved): a timer handled
    late on it is not a caller that missed the board's samples, so nothing is put off."""

    def __init__(self, settings: Settings, stats: LinkStats, emit: Callable[[Event], None]
                 ) -> None:
        self.settings = settings
        self.boards_time = False
        self.stale = False  #: configured on, and not arriving
        self.last_t_us: int | None = None  #: the newest sample's board time
        self.last_at: float | None = None  #: when the newest sample arrived
        self._on: bool | None = None  #: on as confirmed by the board (None: not known)
        self._since = 0.0  #: confirmed on since
        self._period: float | None = None  #: s, TsTimerPeriod as confirmed
        self._seen_period: float | None = None  #: s, from consecutive samples' t_us
        self._stale_from = -math.inf  #: missed samples count from here at the earliest
        self._stats = stats
        self._emit = emit

    @property
    def period(self) -> float | None:
        """The board's telemetry period, s, as confirmed or as seen (``None``: not known)."""
        return self._period or self._seen_period

    def confirmed(self, param: Param, value: int | float, now: float) -> None:
        """The board says ``value`` is in force for ``param``."""
        if param is _GET_DATA:
            on = value == 1
            if on and not self._on:
                self._since = now
            self._on = on
            if not on:
                self.stale = False
        elif param is _PERIOD and isinstance(value, int) and value > 0:
            self._period = value / 1000

    def arrived(self, first: Telemetry, last: Telemetry, now: float) -> None:
        """Samples ``first`` … ``last`` (in counter order) arrived at ``now``: the stream's
        clock, its period as seen, and the end of a stale spell."""
        previous = self.last_t_us
        if self._seen_period is None and previous is not None and last is not first:
            # Consecutive counters: their t_us apart is one period.
            span = (last.t_us - first.t_us) % T_US_WRAP
            count = ((last.counter or 0) - (first.counter or 0)) % COUNTER_MODULUS
            if count and span:
                self._seen_period = span / count / 1e6
        elif self._seen_period is None and previous is not None:
            span = (last.t_us - previous) % T_US_WRAP
            if 0 < span < T_US_WRAP // 2:
                self._seen_period = min(span / 1e6, _LONGEST_PERIOD_S)
        self.last_t_us = last.t_us
        if self.stale:
            self.stale = False
            self._emit(TelemetryResumed(now - (self.last_at or self._since), at=now))
        self.last_at = now

    def board_restarted(self) -> None:
        """Its power-up state: telemetry off, the period its default, no clock yet."""
        self.last_t_us = None
        self._on = None
        self._period = self._seen_period = None
        self.stale = False

    def deadline(self) -> float | None:
        window = self._window()
        return None if window is None else window[0] + window[1]

    def check(self, now: float) -> bool:
        """Whether the stream went stale by ``now`` (said, and counted)."""
        window = self._window()
        if window is None or now < window[0] + window[1]:
            return False
        since, limit = window
        if not self.boards_time and now - (since + limit) > limit / 2:
            # This host's own timer came late: it was not running when the samples were
            # due, and cannot tell a board that stopped from samples it had no chance to
            # read (or, from an emulator starved with it, no chance to be made). Half a
            # window of its own running time decides.
            self._stale_from = now - limit / 2
            return False
        self.stale = True
        self._stats.telemetry_stalls += 1
        self._emit(TelemetryStale(now - since, self.period or 0.001, at=now))
        return True

    def _window(self) -> tuple[float, float] | None:
        """(since when telemetry has been missed, how long it may be), while expected."""
        if not self._on or self.stale:
            return None
        last = self.last_at
        since = max(self._since, self._stale_from, last if last is not None else -math.inf)
        period = self.period
        if period is None:  # not known yet: any period the board allows, then as for 1 ms
            return since, _LONGEST_PERIOD_S + self.settings.stale_periods * 0.001
        return since, self.settings.stale_periods * period
