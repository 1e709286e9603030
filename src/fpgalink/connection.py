"""The sans-I/O link: bytes in, events out; requests in, bytes out; time passed in.

Modelled on h11 and aioquic. Nothing here reads a clock, opens a port or imports asyncio;
the caller passes ``now`` (seconds, any monotonic origin) wherever time matters and drives

* ``receive_data(data, now)``, then ``next_event()`` until it returns ``None``;
* ``send(message, now)``, ``enable(now)``, ``set_param(…, now)`` …, then ``data_to_send()``:
  the one way out for bytes, whoever produced them (the caller's messages, heartbeats,
  resends);
* ``get_timer()`` → when to call ``handle_timer(now)`` next;
* ``port_lost(now, reason)`` and ``reconnected(now)`` when the transport goes and comes back.

The board's real life is reported, never silent, and the connection never drives on
blind: a restart (:class:`~fpgalink.events.BoardRestarted`) or a watchdog lapse
(:class:`~fpgalink.events.WatchdogLapsed`) stops its heartbeat (``RD``: the caller enables
again when it is safe), and after a restart every parameter this side had set is set
again (:class:`~fpgalink.events.BoardResynced`); telemetry configured on that stops coming
is :class:`~fpgalink.events.TelemetryStale`. ``docs/robot.md`` (Faults) has the table.

Bad input from the board never raises: it is an :class:`~fpgalink.protocol.Event`
(:class:`~fpgalink.protocol.Malformed`, :class:`~fpgalink.protocol.NoiseDropped`,
:class:`~fpgalink.events.CounterGap` …) and a counter in :attr:`Connection.stats`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field, fields
from enum import Enum
from typing import Any

from fpgalink.errors import (
    BoardLost,
    FpgalinkError,
    LinkClosed,
    LocalProtocolError,
    ParameterRefused,
    RequestTimeout,
    ValueMismatch,
)
from fpgalink.events import (
    BoardBack,
    BoardFound,
    BoardRestarted,
    BoardResynced,
    BoardSilent,
    CounterDuplicate,
    CounterGap,
    CounterLate,
    EventsDropped,
    RequestDone,
    RequestFailed,
    RestartEvidence,
    TelemetryResumed,
    TelemetryStale,
    WatchdogLapsed,
)
from fpgalink.protocol import (
    COUNTER_MODULUS,
    DEFAULT_FRAMING,
    FLOAT32_MAX,
    TELEMETRY_RUN_MIN,
    AbortReason,
    Alive,
    CountedMessage,
    CounterTracker,
    DirectCommand,
    Disable,
    Enable,
    Event,
    FrameAborted,
    FrameDecoder,
    Framing,
    FramingError,
    Malformed,
    Message,
    MessageId,
    NackReason,
    NoiseDropped,
    Observation,
    Param,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    ParamType,
    References,
    Role,
    SendCounter,
    Telemetry,
    content_length,
    encode_frame,
    encode_message,
    float32,
    lookup,
    parse_content,
    parse_telemetry_run,
)
from fpgalink.protocol.crc import HostWireCrc  # wire CRC (issue 29)
from fpgalink.protocol.wire import MAX_BAUD, MIN_BAUD, byte_time_s

__all__ = [
    "REQUEST_TABLE",
    "Answer",
    "Connection",
    "LinkStats",
    "Liveness",
    "Outcome",
]

_ENABLE, _DISABLE = Enable(), Disable()


def _sendable(role: Role) -> frozenset[type]:
    """The message types ``role`` sends, by their wire IDs (a generic counted message is
    anyone's)."""
    typed = (ParamSet, ParamGet, References, ParamAck, ParamNack, Telemetry)
    direct = (Enable(), Disable(), Alive())
    return frozenset({*(cls for cls in typed if cls.msg_id.sender is role),
                      *(type(cmd) for cmd in direct if cmd.msg_id.sender is role),
                      CountedMessage})


_SENDABLE = {role: _sendable(role) for role in Role}
#: Bytes decoded between two checks of the event cap, so one huge read cannot fill memory.
_RECEIVE_SLICE = 1 << 16
#: Events that are never dropped when the queue overflows: they settle requests or liveness.
#: A TM frame's content bytes: runs of frames this size may be telemetry.
_TM_SIZE = content_length(MessageId.TM)
_KEEP_ON_OVERFLOW = (RequestDone, RequestFailed, BoardFound, BoardSilent, BoardRestarted,
                     BoardResynced, BoardBack, WatchdogLapsed, TelemetryStale,
                     TelemetryResumed)
#: The board's watchdog (SPEC §6): enable falls this long after the last ``RE`` arrived.
WATCHDOG_S = 0.3
#: How far behind this host's time a board's clock may fall over a silence and still be the
#: same run (a sample buffered before this host read it, the host's own timer lateness).
_CLOCK_SLACK_S = 0.1
_CLOCK_SLACK_SHARE = 0.1
#: A setting a restart's resync sets again is asked this many more times when unanswered
#: (each time with the request's own tries) before it counts as failed: answers that come
#: later than one request's tries (a loaded machine) still confirm it.
_RESYNC_ROUNDS = 4
#: The two parameters that say whether, and how often, the board sends telemetry.
_GET_DATA = lookup("GetDataPeriodical")
_PERIOD = lookup("TsTimerPeriod")
_WIRE_CRC = lookup("WireCrc")
_T_US_WRAP = 1 << 32
_WATCHDOG_US = round(WATCHDOG_S * 1e6)
#: Before the telemetry period is known (confirmed or seen), a stream may wait this long for
#: its first samples: the longest period the board allows.
_LONGEST_PERIOD_S = 1.0


class Liveness(Enum):
    UNKNOWN = "unknown"  #: nothing heard since the port (re)opened
    ALIVE = "alive"
    LOST = "lost"  #: silent for longer than the liveness timeout, or the port is gone


# --- the request lifecycle --------------------------------------------------------------------


class Answer(Enum):
    """What the board did about a pending parameter request: the table's input."""

    ECHO = "a PA with the same id, channel, type code and value (any value for a get)"
    OTHER_VALUE = "a PA for the same parameter with another value or type code"
    REFUSED = "a PN for the same parameter"
    NO_ANSWER = "the try's timeout passed without either"
    LINK_DOWN = "the board was lost, the port vanished or the link closed"


class Outcome(Enum):
    DONE = "confirmed: the value is in force"
    RESEND = "send the request again (the next try)"
    FAIL_REFUSED = "failed: the board refused (final)"
    FAIL_MISMATCH = "failed: the board answered with another value"
    FAIL_TIMEOUT = "failed: no answer"
    FAIL_LINK = "failed: the link went down"


#: (answer, another try allowed?) → what happens to the request. Every pending request is
#: settled by this table and nothing else.
REQUEST_TABLE: dict[tuple[Answer, bool], Outcome] = {
    (Answer.ECHO, True): Outcome.DONE,
    (Answer.ECHO, False): Outcome.DONE,
    (Answer.OTHER_VALUE, True): Outcome.RESEND,
    (Answer.OTHER_VALUE, False): Outcome.FAIL_MISMATCH,
    (Answer.REFUSED, True): Outcome.FAIL_REFUSED,
    (Answer.REFUSED, False): Outcome.FAIL_REFUSED,
    (Answer.NO_ANSWER, True): Outcome.RESEND,
    (Answer.NO_ANSWER, False): Outcome.FAIL_TIMEOUT,
    (Answer.LINK_DOWN, True): Outcome.FAIL_LINK,
    (Answer.LINK_DOWN, False): Outcome.FAIL_LINK,
}


@dataclass(slots=True)
class _Request:
    request_id: int
    param: Param
    channel: int
    value: int | float | None  #: None for a get
    deadline: float
    tries: int
    message: ParamSet | ParamGet
    last_answer: ParamAck | None = None  #: the last PA that did not match

    @property
    def what(self) -> str:
        verb = "set" if self.value is not None else "get"
        return f"{verb} {self.param.full_name(self.channel)}"

    def answer_to(self, ack: ParamAck) -> Answer:
        """Whether ``ack`` confirms this request: same type code, and for a set exactly the
        value sent (float32-exact for floats; never raises on any value the board sends)."""
        if ack.value_type != self.param.type:
            return Answer.OTHER_VALUE
        if self.value is None:
            return Answer.ECHO
        if self.param.type is ParamType.FLOAT:
            same = float32(float(self.value)) == ack.value
        else:
            same = isinstance(ack.value, int) and ack.value == self.value
        return Answer.ECHO if same else Answer.OTHER_VALUE


@dataclass(slots=True)
class LinkStats:
    """Everything the link counted, each count kept here only. ``snapshot()`` copies."""

    bytes_received: int = 0
    bytes_sent: int = 0
    frames_received: int = 0
    frames_sent: int = 0
    messages_received: int = 0
    telemetry_received: int = 0
    alive_received: int = 0
    noise_bytes: int = 0
    aborted_frames: int = 0  #: restarted by an unescaped START
    overflows: int = 0  #: content over the limit
    malformed: int = 0
    lost: int = 0  #: counter gaps net of late arrivals
    duplicates: int = 0
    reordered: int = 0
    #: counters judged damaged: a jump the next counter did not confirm (no checksum)
    corrupt_counters: int = 0
    retries: int = 0  #: parameter requests resent
    echo_mismatches: int = 0  #: PA echoes with another value than the pending request's
    heartbeats_sent: int = 0
    heartbeat_misses: int = 0  #: times the board went silent past the liveness timeout
    restarts: int = 0  #: the board restarted (or may have: out of reach, reconnected)
    resync_failures: int = 0  #: parameters that could not be set again after a restart
    watchdog_lapses: int = 0  #: the board's watchdog disabled it while it was meant enabled
    telemetry_stalls: int = 0  #: telemetry configured on stopped coming
    #: references replaced by a newer one before the line had room to send them
    references_superseded: int = 0
    #: requests refused by the asyncio link, the line backed up (``LineBusy``)
    line_busy: int = 0
    events_dropped: int = 0
    subscriber_drops: int = 0  #: telemetry samples a slow subscriber lost (asyncio layer)
    port_losses: int = 0
    reconnects: int = 0
    #: frames dropped because their wire CRC did not match (only while the CRC is on)
    crc_failures: int = 0
    malformed_by_reason: dict[str, int] = field(default_factory=dict)

    def snapshot(self) -> LinkStats:
        copy = LinkStats(**{f.name: getattr(self, f.name) for f in fields(self)})
        copy.malformed_by_reason = dict(self.malformed_by_reason)
        return copy

    def as_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def decode_errors(self) -> int:
        return self.aborted_frames + self.overflows + self.malformed


class Connection:
    """One link to one board (or, with ``role=Role.BOARD``, the board's side of it).

    ``baud`` lets the connection know how fast the line drains, so references never queue
    behind more than ``max_reference_delay`` of earlier bytes: a newer ``RV`` replaces one
    still waiting (only the newest reference matters) and the replacement is counted in
    :attr:`LinkStats.references_superseded`. ``None`` sends every ``RV`` at once.

    ``heartbeat_give_up``: a heartbeat due when the last ``RE`` went out this long ago (the
    caller's loop stalled) is not sent: the board's 300 ms watchdog has lapsed or is about
    to, clearing its references, and a late ``RE`` would enable it again with none. The
    connection sends ``RD`` instead and reports :class:`~fpgalink.events.WatchdogLapsed`.
    ``stale_periods``: telemetry configured on (``GetDataPeriodical`` = 1 confirmed on this
    link) and none for this many timer periods is :class:`~fpgalink.events.TelemetryStale`.
    """

    def __init__(
        self,
        role: Role = Role.HOST,
        *,
        framing: Framing = DEFAULT_FRAMING,
        baud: int | None = 1_000_000,
        heartbeat_interval: float = 0.1,
        liveness_timeout: float = 0.7,
        request_timeout: float = 0.05,
        request_tries: int = 8,
        max_reference_delay: float = 0.005,
        max_events: int = 65536,
        heartbeat_give_up: float = 0.28,
        stale_periods: int = 50,
    ) -> None:
        if not 0 < heartbeat_interval < WATCHDOG_S:
            raise ValueError(
                f"heartbeat_interval must be below the board's 300 ms watchdog, got "
                f"{heartbeat_interval!r} s"
            )
        if not heartbeat_interval < heartbeat_give_up <= WATCHDOG_S:
            raise ValueError(
                f"heartbeat_give_up must be above the heartbeat interval and at most the "
                f"board's 300 ms watchdog, got {heartbeat_give_up!r} s"
            )
        if not (isinstance(stale_periods, int) and stale_periods >= 2):
            raise ValueError(f"stale_periods must be a whole number ≥ 2, got {stale_periods!r}")
        for name, value in (("request_timeout", request_timeout),
                            ("liveness_timeout", liveness_timeout),
                            ("max_reference_delay", max_reference_delay)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number of seconds, "
                                 f"got {value!r}")
        if request_tries < 1 or max_events < 1:
            raise ValueError("request_tries and max_events must be at least 1")
        if baud is not None and not (isinstance(baud, int) and MIN_BAUD <= baud <= MAX_BAUD):
            raise ValueError(f"baud must be a whole number from {MIN_BAUD:,} to {MAX_BAUD:,}, "
                             f"got {baud!r}")
        self.role = role
        self._sendable = _SENDABLE[role]
        self.framing = framing
        self.heartbeat_interval = heartbeat_interval
        self.liveness_timeout = liveness_timeout
        self.request_timeout = request_timeout
        self.request_tries = request_tries
        self.max_reference_delay = max_reference_delay
        self.heartbeat_give_up = heartbeat_give_up
        self.stale_periods = stale_periods
        self.stats = LinkStats()
        self.counter_tracker = CounterTracker()
        self.latest_telemetry: Telemetry | None = None
        self.liveness = Liveness.UNKNOWN
        self.enabled = False  #: we send ``RE`` every heartbeat interval
        self.baud = baud  #: the line's bit rate (None: not known, no pacing)
        #: ``now`` is the board's own time (an emulated board in the caller's process, whose
        #: time trails the wall clock when the process is starved): a timer handled late on
        #: it is not a caller that missed the board's samples, so nothing is put off for it.
        self.boards_time = False
        self._byte_time = byte_time_s(baud) if baud is not None else 0.0
        self._decoder = FrameDecoder(framing)
        self._send_counter = SendCounter()
        self._events: deque[Event] = deque()
        self._max_events = max_events
        self._outbox: list[bytes] = []
        self._port_up = True
        self._last_heard: float | None = None
        self._liveness_origin: float | None = None
        self._next_heartbeat: float | None = None
        self._line_free_at = 0.0  #: when the bytes handed out so far have left the line
        self._held_reference: References | None = None
        self._requests: dict[int, _Request] = {}
        self._next_request_id = 1
        #: every parameter this side set and the board confirmed, in the order first set:
        #: the configuration it holds, set again after the board restarts
        self.held: dict[tuple[int, int], tuple[Param, int, int | float]] = {}
        #: values sent in a set the board has not confirmed since (unanswered, or still
        #: under way): it may hold any of them, so a probe reading one is no lost setting
        self._unconfirmed: dict[tuple[int, int], set[int | float]] = {}
        self._last_heartbeat_at: float | None = None  #: when the last RE was queued
        self._enable_seen = False  #: the board's telemetry showed it enabled by this link
        self._saw_disabled = False  #: since enable(), a sample showed the board disabled
        self._enabled_since_us: int | None = None  #: since enable(), enabled from this t_us
        #: telemetry: on as confirmed by the board (None: not known), since when, its period
        self._telemetry_on: bool | None = None
        self._telemetry_since = 0.0
        self._period: float | None = None  #: s, TsTimerPeriod as confirmed
        self._seen_period: float | None = None  #: s, from consecutive samples' t_us
        self._last_telemetry_at: float | None = None  #: when the last TM arrived
        self._stale_from = -math.inf  #: missed samples count from here at the earliest
        self._last_t_us: int | None = None
        self.telemetry_stale = False  #: configured on, and not arriving
        self._probe: int | None = None  #: the request asking a stale board for its setting
        #: a restart's resync: what is still to set, the request in flight, the outcome
        self._resync: deque[tuple[Param, int, int | float]] | None = None
        self._resync_request: int | None = None
        self._resync_rounds = 0  #: the setting being set again: times it went unanswered
        self._resync_applied = 0
        self._resync_failed: list[tuple[str, FpgalinkError]] = []
        #: the board was out of reach since then (``where``: "" or on the reconnected
        #: port): when heard again it may have restarted
        self._out_of_reach: tuple[str, float] | None = None
        #: heard again after it was out of reach: what the next counter will decide about
        self._verify: str | None = None
        self._last_duplicate: int | None = None
        # --- wire CRC (issue 29): off until the board confirms WireCrc = 1 ----------------
        #: the optional wire CRC's state (:class:`~fpgalink.protocol.crc.HostWireCrc`)
        self.wire_crc = HostWireCrc()

    # --- receiving ------------------------------------------------------------------------

    def receive_data(self, data: bytes | bytearray | memoryview, now: float) -> None:
        """Feed bytes from the wire that arrived at ``now``."""
        self.stats.bytes_received += len(data)
        if len(data) <= _RECEIVE_SLICE:
            self._receive(data, now)
            return
        view = memoryview(data)
        for start in range(0, len(view), _RECEIVE_SLICE):
            self._receive(view[start : start + _RECEIVE_SLICE], now)

    def _receive(self, data: bytes | bytearray | memoryview, now: float) -> None:
        decoder = self._decoder
        before = decoder.stats.frames
        items = decoder.feed(data)
        # --- wire CRC (issue 29): checked and stripped before any frame is parsed --------
        if self.wire_crc.checking and items:
            items, failed = self.wire_crc.filter(items)
            if failed:
                self.stats.crc_failures += failed
                before += failed  # those items are CrcMismatch events now, not frames
        # ----------------------------------------------------------------------------------
        if items:
            n = len(items)
            if n < TELEMETRY_RUN_MIN:
                self._each(items, now)
            # Every item a frame (the decoder counted one per item) and every frame a TM:
            # the 1 kHz case, a chunk at a time.
            elif decoder.stats.frames - before != n or not self._telemetry(items, now):
                self._mixed(items, now)
        if len(self._events) > self._max_events:
            self._trim_events()
        if self.liveness is Liveness.ALIVE:
            self._last_heard = now
            if self._resync is not None and self._resync_request is None and not self._verify:
                # Heard going on after a silence paused the resync: it goes on from the
                # setting it was at (whether that one took is not known).
                self._resync_next(now)

    def _mixed(self, items: list[bytes | FramingError], now: float) -> None:
        """Items that are not all TM: runs of TM-sized frames long enough to gain go a run at
        a time, everything else one by one, in stream order."""
        size = _TM_SIZE
        odd = [i for i, item in enumerate(items) if type(item) is not bytes or len(item) != size]
        done = 0  # items before this one are handled
        previous = -1  # the odd item before the run being looked at
        for i in (*odd, len(items)):
            if i - previous - 1 >= TELEMETRY_RUN_MIN:
                if previous + 1 > done:
                    self._each(items[done : previous + 1], now)
                run = items[previous + 1 : i]
                if not self._telemetry(run, now):
                    self._each(run, now)
                done = i
            previous = i
        if done < len(items):
            self._each(items[done:], now)

    def _telemetry(self, frames: list[Any], now: float) -> bool:
        """Take ``frames`` as TM events if every one is a well-formed TM (what
        ``parse_content`` would make of each); otherwise leave them and return False."""
        telemetry = parse_telemetry_run(frames)
        if telemetry is None:
            return False
        n = len(telemetry)
        counters: list[int] = [tm.counter for tm in telemetry]  # type: ignore[misc]
        if self.liveness is not Liveness.ALIVE:
            # The board is known to be there before the message that shows it.
            self._found(now)
        first = counters[0]
        if (counters == list(range(first, first + n))
                and self.counter_tracker.observe_in_order(first, n)):
            if self._verify is not None:
                self._back()
            if self.enabled:
                self._watch_enable(telemetry, now)
            self._events.extend(telemetry)
            self._telemetry_arrived(telemetry[0], telemetry[-1], now)
        else:
            for msg in telemetry:
                self._one_telemetry(msg, now)
        stats = self.stats
        stats.frames_received += n
        stats.messages_received += n
        stats.telemetry_received += n
        self.latest_telemetry = telemetry[-1]
        return True

    def _one_telemetry(self, msg: Telemetry, now: float) -> None:
        """A TM off the in-order fast path: its counter and clock judged, in stream order."""
        counter = msg.counter
        assert counter is not None
        tracker = self.counter_tracker
        last_t_us = self._last_t_us
        if tracker.observe_in_order(counter):
            if self._verify is not None:
                self._back()
        elif (last_t_us is not None
                and 0 < (last_t_us - msg.t_us) % _T_US_WRAP < _T_US_WRAP // 2):
            # Its clock went back and its counter broke the sequence with it: a restarted
            # board (a damaged t_us alone comes with the counter in order).
            self._restarted(RestartEvidence.CLOCK_BACKWARDS,
                            f"t_us {msg.t_us} after {last_t_us}, counter {counter:05d} "
                            f"where {tracker.expected:05d} was expected", now)
            tracker.observe(counter)
        elif (self._verify is not None and last_t_us is not None
                and self._last_telemetry_at is not None
                and self._clock_behind(msg.t_us, last_t_us, now - self._last_telemetry_at)):
            board_s = (msg.t_us - last_t_us) % _T_US_WRAP / 1e6
            self._restarted(RestartEvidence.CLOCK_BEHIND,
                            f"{board_s:.3f} s of board time over "
                            f"{now - self._last_telemetry_at:.3f} s of this host's, counter "
                            f"{counter:05d} where {tracker.expected:05d} was expected", now)
            tracker.observe(counter)
        else:
            self._count_out_of_order(counter, now)
        if self.enabled:
            self._watch_enable((msg,), now)
        self._events.append(msg)
        self._telemetry_arrived(msg, msg, now)

    @staticmethod
    def _clock_behind(t_us: int, last_t_us: int, host_s: float) -> bool:
        """Over a silence a board that ran on counted about the host's time; one that
        restarted meanwhile counted only from its power-up. The slack covers a sample that
        waited in a buffer before this host read it."""
        board_s = (t_us - last_t_us) % _T_US_WRAP / 1e6
        return board_s < host_s - (_CLOCK_SLACK_S + _CLOCK_SLACK_SHARE * host_s)

    def _telemetry_arrived(self, first: Telemetry, last: Telemetry, now: float) -> None:
        """Samples ``first`` … ``last`` (in counter order) arrived at ``now``: the stream's
        clock, its period as seen, and the end of a stale spell."""
        previous = self._last_t_us
        if self._seen_period is None and previous is not None and last is not first:
            # Consecutive counters: their t_us apart is one period.
            span = (last.t_us - first.t_us) % _T_US_WRAP
            count = ((last.counter or 0) - (first.counter or 0)) % COUNTER_MODULUS
            if count and span:
                self._seen_period = span / count / 1e6
        elif self._seen_period is None and previous is not None:
            span = (last.t_us - previous) % _T_US_WRAP
            if 0 < span < _T_US_WRAP // 2:
                self._seen_period = min(span / 1e6, _LONGEST_PERIOD_S)
        self._last_t_us = last.t_us
        if self.telemetry_stale:
            self.telemetry_stale = False
            gap = now - (self._last_telemetry_at or self._telemetry_since)
            self._events.append(TelemetryResumed(gap))
        self._last_telemetry_at = now

    def _watch_enable(self, samples: Any, now: float) -> None:
        """The link keeps the board enabled. Once its telemetry has shown it enabled by this
        link's ``RE``, a sample showing it disabled means the board disabled itself.

        Shown enabled by this link: samples still on the way when ``enable()`` was called
        may show it enabled from before an ``RD`` (then disabled, then enabled): so it is a
        rise from disabled to enabled, or enabled samples spanning the watchdog's 300 ms of
        board time (no earlier enable outlives that without this link's ``RE``)."""
        if self._enable_seen:
            for sample in samples:
                if not sample.a.flags & 1:
                    self._lapse(now, None, "its telemetry shows it disabled after it was "
                                "enabled, while this host kept sending RE: the RE came more "
                                "than 300 ms apart at the board, or an RD came from "
                                "elsewhere")
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
            elif (sample.t_us - self._enabled_since_us) % _T_US_WRAP >= _WATCHDOG_US:
                self._enable_seen = True
            if self._enable_seen:
                self._watch_enable(samples[index + 1:], now)
                return

    def _count(self, counter: int, now: float) -> None:
        if not self.counter_tracker.observe_in_order(counter):
            self._count_out_of_order(counter, now)
        elif self._verify is not None:
            self._back()

    def _count_out_of_order(self, counter: int, now: float) -> None:
        """Anything but the expected counter, the wrap included, is the tracker's to judge;
        a sequence starting again is a restart, not copies."""
        tracker = self.counter_tracker
        expected = tracker.expected
        observation = tracker.observe(counter)
        if observation is Observation.DUPLICATE:
            previous, self._last_duplicate = self._last_duplicate, counter
            run = previous == (counter - 1) % COUNTER_MODULUS
            if counter == 0 or run:
                # Back to 00000, or counting on from behind: a new sequence, not copies.
                tracker.duplicates -= 1 + run
                self.stats.duplicates -= run
                self._restarted(RestartEvidence.COUNTER_RESET,
                                f"counter {counter:05d} where {expected:05d} was expected",
                                now)
                tracker.observe(counter)
                return
        else:
            self._last_duplicate = None
        if self._verify is not None:
            self._back()
        self._counter_event(observation, counter)

    def _each(self, items: list[bytes | FramingError], now: float) -> None:
        """Items one at a time: framing errors, and frames through ``parse_content``."""
        stats = self.stats
        events = self._events
        append = events.append
        frames = telemetry = counted = 0
        latest: Telemetry | None = None
        found = self.liveness is Liveness.ALIVE
        for item in items:
            if type(item) is not bytes:
                assert isinstance(item, FramingError)
                self._framing_event(item)
                continue
            frames += 1
            msg = parse_content(item)
            if isinstance(msg, Malformed):
                stats.malformed += 1
                key = msg.reason.name
                stats.malformed_by_reason[key] = stats.malformed_by_reason.get(key, 0) + 1
                append(msg)
                continue
            if type(msg) is ParamNack and msg.error == NackReason.NOT_CONTROLLER:
                # The router's answer, not the board's: no part of the board's counter
                # sequence, and no sign that the board is there.
                self._answer(msg, now)
                append(msg)
                continue
            if not found:
                # The board is known to be there before the message that shows it.
                self._found(now)
                found = True
            if type(msg) is Telemetry:
                telemetry += 1
                self._one_telemetry(msg, now)
                latest = msg
                continue
            elif isinstance(msg, DirectCommand):
                if type(msg) is Alive:
                    stats.alive_received += 1
                append(msg)
                continue
            else:
                counter = msg.counter
                if type(msg) is ParamAck or type(msg) is ParamNack:
                    self._answer(msg, now)
            counted += 1
            assert counter is not None
            self._count(counter, now)
            append(msg)
        stats.frames_received += frames
        stats.messages_received += counted + telemetry
        if telemetry:
            stats.telemetry_received += telemetry
            self.latest_telemetry = latest

    def _trim_events(self) -> None:
        events = self._events
        excess = len(events) - self._max_events
        kept: list[Event] = []
        dropped = 0
        while dropped < excess and events:
            event = events.popleft()
            if isinstance(event, _KEEP_ON_OVERFLOW):
                kept.append(event)
            else:
                dropped += 1
        events.extendleft(reversed(kept))
        self.stats.events_dropped += dropped
        events.append(EventsDropped(dropped))

    def _framing_event(self, item: FramingError) -> None:
        stats = self.stats
        if isinstance(item, NoiseDropped):
            stats.noise_bytes += item.dropped
        elif isinstance(item, FrameAborted):
            if item.reason is AbortReason.OVERFLOW:
                stats.overflows += item.count
            else:
                stats.aborted_frames += item.count
        self._events.append(item)

    def _counter_event(self, observation: Observation, counter: int) -> None:
        tracker = self.counter_tracker
        if observation is Observation.GAP:
            self._events.append(CounterGap(tracker.last_gap, counter))
        elif observation is Observation.DUPLICATE:
            self.stats.duplicates += 1
            self._events.append(CounterDuplicate(counter))
        elif observation is Observation.LATE:
            self.stats.reordered += 1
            self._events.append(CounterLate(counter))
        elif observation is Observation.CORRUPT:
            self.stats.corrupt_counters += 1
        self.stats.lost = tracker.lost

    def next_event(self) -> Event | None:
        """The oldest pending event, or ``None`` when there is none."""
        return self._events.popleft() if self._events else None

    def events(self) -> Iterator[Event]:
        """Drain every pending event."""
        events = self._events  # the one queue, for the connection's life
        while events:
            yield events.popleft()

    @property
    def pending_events(self) -> int:
        return len(self._events)

    # --- sending --------------------------------------------------------------------------

    def send(self, message: Message | CountedMessage | DirectCommand, now: float) -> None:
        """Queue ``message`` for :meth:`data_to_send`; a counted message takes the next
        counter value when it goes out. A reference may wait for line room (see the class)."""
        if type(message) not in self._sendable:
            raise LocalProtocolError(f"a {self.role.value} does not send {type(message).__name__}")
        if type(message) is References:
            if not (abs(message.ref_a) <= FLOAT32_MAX and abs(message.ref_b) <= FLOAT32_MAX):
                # NaN fails the comparison too. Checked here, not at encoding: a held
                # reference is encoded later, where an error would surface far from its cause.
                raise LocalProtocolError(
                    f"references must be finite numbers within the float32 range, got "
                    f"({message.ref_a!r}, {message.ref_b!r})"
                )
            if self._byte_time and self._line_free_at - now > self.max_reference_delay:
                if self._held_reference is not None:
                    self.stats.references_superseded += 1
                self._held_reference = message
                return
        self._queue(message, now)

    def data_to_send(self) -> bytes:
        """Every byte to write to the port now, in order."""
        outbox = self._outbox
        if not outbox:
            return b""
        out = outbox[0] if len(outbox) == 1 else b"".join(outbox)
        outbox.clear()
        return out

    def _queue(self, message: Message | CountedMessage | DirectCommand, now: float) -> None:
        if isinstance(message, DirectCommand):
            content = message.content
        else:
            content = encode_message(message, self._send_counter.take())
            # --- wire CRC (issue 29) ------------------------------------------------------
            self.wire_crc.sent(message)
            content = self.wire_crc.outgoing(content)
            # -------------------------------------------------------------------------------
        wire = encode_frame(content, self.framing)
        self._outbox.append(wire)
        stats = self.stats
        stats.frames_sent += 1
        stats.bytes_sent += len(wire)
        if self._byte_time:
            free = self._line_free_at
            self._line_free_at = (now if now > free else free) + len(wire) * self._byte_time

    @property
    def next_counter(self) -> int:
        """The counter value the next counted message will carry."""
        return self._send_counter.value

    # --- heartbeat and liveness -----------------------------------------------------------

    def start(self, now: float) -> None:
        """Begin expecting the board: silence from ``now`` on counts."""
        self._liveness_origin = now

    def enable(self, now: float) -> None:
        """Send ``RE`` now and every ``heartbeat_interval`` until :meth:`disable` (or until
        the board restarts or its watchdog lapses: then enable again)."""
        if not self.enabled:
            self._enable_seen = self._saw_disabled = False
            self._enabled_since_us = None
        self.enabled = True
        self._heartbeat(now)

    def disable(self, now: float) -> None:
        """Stop the heartbeat and send ``RD`` (the board drops enable at once)."""
        self.enabled = False
        self._enable_seen = False
        self._next_heartbeat = None
        if self._port_up:
            self._queue(_DISABLE, now)

    def _heartbeat(self, now: float) -> None:
        if self._port_up:
            self._queue(_ENABLE, now)
            self.stats.heartbeats_sent += 1
            self._last_heartbeat_at = now
        self._next_heartbeat = now + self.heartbeat_interval

    def _lapse(self, now: float, host_silent_for: float | None, detail: str) -> None:
        """The board is (or is about to be) disabled by its watchdog while meant enabled:
        stop keeping it enabled, make it definite with ``RD``, and say so."""
        self.disable(now)
        self.stats.watchdog_lapses += 1
        self._events.append(WatchdogLapsed(host_silent_for, detail))

    def _found(self, now: float) -> None:
        self.liveness = Liveness.ALIVE
        self._events.append(BoardFound())
        if self._out_of_reach is not None:
            # It may have restarted while out of reach, or not: its next counter decides
            # (back at 00000, or going on), and a question makes sure one comes.
            where, since = self._out_of_reach
            self._out_of_reach = None
            self._verify = f"heard again after {now - since:.3f} s of silence{where}"
            if self._probe is None:
                self._probe = self.get_param(_WIRE_CRC if self.wire_crc.on else _GET_DATA,
                                             0, now)

    def _back(self) -> None:
        """The board heard again went on counting: it did not restart."""
        detail, self._verify = self._verify, None
        assert detail is not None
        self._drop_probe()
        self._events.append(BoardBack(detail))

    def _drop_probe(self) -> None:
        """The question the probe asked is answered otherwise: its request goes, unsaid."""
        if self._probe is not None:
            self._requests.pop(self._probe, None)
            self._probe = None

    @property
    def verifying(self) -> bool:
        """Heard again after a silence or on a reconnected port, and not yet known whether
        the board restarted meanwhile."""
        return self._verify is not None

    # --- the board's restarts ---------------------------------------------------------------

    def _restarted(self, evidence: RestartEvidence, detail: str, now: float) -> None:
        """The board restarted (or may have): it runs its power-up state — disabled,
        telemetry off, parameters at their power-up values, counters from 0. Stop keeping
        it enabled, follow its new counter sequence, and set again what this side holds."""
        self.stats.restarts += 1
        if self._verify is not None:
            detail += f"; {self._verify}"
            self._verify = None
        self._events.append(BoardRestarted(evidence, detail))
        self._unconfirmed.clear()  # its power-up values now, whatever was sent before
        self.counter_tracker.reset()
        self._last_duplicate = None
        if self.enabled:
            self.disable(now)
        self._enable_seen = False
        self.latest_telemetry = None
        self._last_t_us = None
        # A board powers up on the plain wire (WireCrc 0); held, it is set again first.
        self.wire_crc.on = self.wire_crc.asking = False
        self._telemetry_on = None
        self._period = self._seen_period = None
        self.telemetry_stale = False
        self._drop_probe()
        self.resync(now)

    def resync(self, now: float) -> None:
        """Set again, one at a time, every parameter this side holds, as after a restart
        (done by itself then); :class:`~fpgalink.events.BoardResynced` says how it went.
        The caller asks for it again after one that failed for want of answers."""
        if self._resync_request is not None:
            self._requests.pop(self._resync_request, None)
        # The wire CRC first (every later message then carries it, as before), telemetry
        # last, so the stream comes back from a board configured as before.
        settings = sorted(self.held.values(),
                          key=lambda held: (held[0] is _GET_DATA) - (held[0] is _WIRE_CRC))
        self._resync = deque(settings)
        self._resync_request = None
        self._resync_rounds = 0
        self._resync_applied = 0
        self._resync_failed = []
        self._resync_next(now)

    def _resync_next(self, now: float) -> None:
        """Set the next held parameter again (one at a time: the board's RX RAM holds two
        frames), or report the resync done."""
        queue = self._resync
        if queue is None:
            return
        if queue:
            param, channel, value = queue.popleft()
            self._resync_request = self.set_param(param, channel, value, now)
            return
        self._resync = self._resync_request = None
        failed = tuple(self._resync_failed)
        self.stats.resync_failures += len(failed)
        self._events.append(BoardResynced(self._resync_applied, failed))

    def hold(self, param: Param, channel: int, value: int | float) -> None:
        """Keep ``value`` (the board's, as read) as this side's configuration for
        ``param``: set again after the board restarts, as a value set here would be."""
        self.held.setdefault((param.id, channel), (param, channel, value))

    @property
    def resyncing(self) -> bool:
        """The board restarted and the configuration this side holds is being set again."""
        return self._resync is not None

    # --- telemetry expected ---------------------------------------------------------------

    def _confirmed(self, param: Param, channel: int, value: int | float, now: float) -> None:
        """The board says ``value`` is in force for ``param``: follow what the telemetry
        stream should be."""
        if param is _GET_DATA:
            on = value == 1
            if on and not self._telemetry_on:
                self._telemetry_since = now
            self._telemetry_on = on
            if not on:
                self.telemetry_stale = False
        elif param is _PERIOD and isinstance(value, int) and value > 0:
            self._period = value / 1000

    def _stale_window(self) -> tuple[float, float] | None:
        """(since when telemetry has been missed, how long it may be), while expected."""
        if not self._telemetry_on or self.telemetry_stale or not self._port_up:
            return None
        last = self._last_telemetry_at
        since = max(self._telemetry_since, self._stale_from,
                    last if last is not None else -math.inf)
        period = self._period or self._seen_period
        if period is None:  # not known yet: any period the board allows, then as for 1 ms
            return since, _LONGEST_PERIOD_S + self.stale_periods * 0.001
        return since, self.stale_periods * period

    def _stale_deadline(self) -> float | None:
        window = self._stale_window()
        return None if window is None else window[0] + window[1]

    @property
    def telemetry_period(self) -> float | None:
        """The board's telemetry period, s, as confirmed or as seen (``None``: not known)."""
        return self._period or self._seen_period

    def get_timer(self) -> float | None:
        """The next time :meth:`handle_timer` has work to do, or ``None``."""
        deadlines = [r.deadline for r in self._requests.values()]
        if self._next_heartbeat is not None and self._port_up:
            deadlines.append(self._next_heartbeat)
        silence = self._silence_deadline()
        if silence is not None:
            deadlines.append(silence)
        if self._held_reference is not None:
            deadlines.append(self._line_free_at - self.max_reference_delay)
        stale = self._stale_deadline()
        if stale is not None:
            deadlines.append(stale)
        return min(deadlines) if deadlines else None

    def _silence_deadline(self) -> float | None:
        if self.liveness is Liveness.LOST:
            return None
        origin = self._last_heard if self._last_heard is not None else self._liveness_origin
        return None if origin is None else origin + self.liveness_timeout

    def handle_timer(self, now: float) -> None:
        if self._next_heartbeat is not None and now >= self._next_heartbeat:
            last = self._last_heartbeat_at
            if self.enabled and last is not None and now - last >= self.heartbeat_give_up:
                # Overdue past the board's watchdog: the caller stalled. Supervision
                # decides what happens next, not a late RE.
                self._lapse(now, now - last, f"this host sent no RE for {now - last:.3f} s")
            else:
                self._heartbeat(now)
        held = self._held_reference
        if held is not None and self._line_free_at - now <= self.max_reference_delay:
            self._held_reference = None
            self._queue(held, now)
        silence = self._silence_deadline()
        if silence is not None and now >= silence:
            origin = self._last_heard if self._last_heard is not None else self._liveness_origin
            assert origin is not None
            self.liveness = Liveness.LOST
            self.stats.heartbeat_misses += 1
            self._events.append(BoardSilent(now - origin))
            self._out_of_reach = ("", origin)
            self._settle_all(BoardLost(f"board silent for {now - origin:.3f} s"))
        for request in list(self._requests.values()):
            if now >= request.deadline:
                self._settle(request, Answer.NO_ANSWER, now)
        window = self._stale_window()
        if window is not None and now >= window[0] + window[1]:
            since, limit = window
            if not self.boards_time and now - (since + limit) > limit / 2:
                # This host's own timer came late: it was not running when the samples
                # were due, and cannot tell a board that stopped from samples it had no
                # chance to read (or, from an emulator starved with it, no chance to be
                # made). Half a window of its own running time decides.
                self._stale_from = now - limit / 2
                return
            self.telemetry_stale = True
            self.stats.telemetry_stalls += 1
            self._events.append(TelemetryStale(now - since, self.telemetry_period or 0.001))
            if self._probe is None and self._resync is None and self.liveness is Liveness.ALIVE:
                # Ask the board what it has: a restart shows as telemetry off (and as its
                # counter back at 00000 on the answer). On the CRC wire, ask for WireCrc: a
                # restarted board is back on the plain wire and understands that question
                # in either form, and its answer is taken in either form.
                self._probe = self.get_param(_WIRE_CRC if self.wire_crc.on else _GET_DATA,
                                             0, now)

    # --- the port -------------------------------------------------------------------------

    def port_lost(self, now: float, reason: str) -> None:
        """The transport went away: pending requests fail, nothing is sent until
        :meth:`reconnected`."""
        self.stats.port_losses += 1
        self._port_up = False
        since = now if self._out_of_reach is None else self._out_of_reach[1]
        self._out_of_reach = (", on the reconnected port", since)
        self.liveness = Liveness.LOST
        # No heartbeat can reach the board: its watchdog lapses. Nothing enables it again
        # by itself when the port comes back; the caller decides.
        self.enabled = False
        self._enable_seen = False
        self._next_heartbeat = None
        self._outbox.clear()
        self._held_reference = None
        self._settle_all(BoardLost(reason))

    def reconnected(self, now: float) -> None:
        """A new transport to the board: liveness is judged anew from ``now``. The link was
        disabled when the port went; when the board is heard again its counter says whether
        it restarted meanwhile (:class:`~fpgalink.events.BoardRestarted`: what this side
        holds is set again) or went on (:class:`~fpgalink.events.BoardBack`: what it sent
        meanwhile is counted lost). The caller enables again when it is safe."""
        self.stats.reconnects += 1
        self._port_up = True
        self._decoder.reset()
        self.liveness = Liveness.UNKNOWN
        self._last_heard = None
        self._liveness_origin = now
        self._line_free_at = now

    def close(self, now: float) -> None:
        """Stop the heartbeat (queueing ``RD`` if enabled) and fail pending requests with
        :class:`~fpgalink.errors.LinkClosed`."""
        if self.enabled:
            self.disable(now)
        self._next_heartbeat = None
        self._held_reference = None
        self._settle_all(LinkClosed("link closed while the request was pending"))

    # --- parameter requests ---------------------------------------------------------------

    def set_param(self, param: Param, channel: int, value: int | float, now: float) -> int:
        """Send ``PS`` (already validated by the caller via :meth:`Param.coerce`); returns
        a request id that a :class:`RequestDone` or :class:`RequestFailed` event will carry."""
        message = ParamSet(param.id, channel, int(param.type), value)
        return self._start_request(param, channel, value, message, now)

    def get_param(self, param: Param, channel: int, now: float) -> int:
        return self._start_request(param, channel, None, ParamGet(param.id, channel), now)

    def _start_request(
        self, param: Param, channel: int, value: int | float | None,
        message: ParamSet | ParamGet, now: float,
    ) -> int:
        request_id = self._next_request_id
        self._next_request_id += 1
        request = _Request(request_id, param, channel, value, now + self.request_timeout, 1,
                           message)
        self._requests[request_id] = request
        if value is not None:
            self._unconfirmed.setdefault((param.id, channel), set()).add(
                float32(float(value)) if param.type is ParamType.FLOAT else value)
        self._queue(message, now)
        return request_id

    def _answer(self, msg: ParamAck | ParamNack, now: float) -> None:
        """Settle the pending requests for the parameter ``msg`` is about."""
        # --- wire CRC (issue 29): the board's PA for WireCrc sets the mode ----------------
        self.wire_crc.answered(msg.param_id, msg.value if type(msg) is ParamAck else None)
        # ----------------------------------------------------------------------------------
        waiting = [r for r in self._requests.values()
                   if r.param.id == msg.param_id and r.channel == msg.channel]
        if not waiting:
            return
        if isinstance(msg, ParamNack):
            for request in waiting:
                self._settle(request, Answer.REFUSED, now, msg)
            return
        # The first request this echo confirms takes it; for every other, it is another value.
        for request in waiting:
            if request.answer_to(msg) is Answer.ECHO:
                self._settle(request, Answer.ECHO, now, msg)
                return
        for request in waiting:
            self.stats.echo_mismatches += 1
            request.last_answer = msg
            self._settle(request, Answer.OTHER_VALUE, now, msg)

    def _settle(self, request: _Request, answer: Answer, now: float,
                msg: ParamAck | ParamNack | None = None,
                error: FpgalinkError | None = None) -> None:
        outcome = REQUEST_TABLE[(answer, request.tries < self.request_tries)]
        if outcome is Outcome.RESEND:
            request.tries += 1
            request.deadline = now + self.request_timeout
            self.stats.retries += 1
            self._queue(request.message, now)
            return
        del self._requests[request.request_id]
        if outcome is Outcome.DONE:
            assert isinstance(msg, ParamAck)
            self._events.append(RequestDone(request.request_id, request.param, request.channel,
                                            msg.value, request.tries))
            self._done(request, msg.value, now)
            return
        if outcome is Outcome.FAIL_REFUSED:
            assert isinstance(msg, ParamNack)
            error = ParameterRefused(request.param.full_name(request.channel), msg.channel,
                                     msg.reason, msg.error)
        elif outcome is Outcome.FAIL_MISMATCH:
            assert isinstance(msg, ParamAck)
            error = ValueMismatch(request.what, request.tries, request.value, msg.value,
                                  msg.value_type)
        elif outcome is Outcome.FAIL_TIMEOUT:
            if request.last_answer is not None:
                last = request.last_answer
                error = ValueMismatch(request.what, request.tries, request.value, last.value,
                                      last.value_type)
            else:
                error = RequestTimeout(request.what, request.tries, self.request_timeout)
        assert error is not None
        self._events.append(RequestFailed(request.request_id, request.param, request.channel,
                                          error, request.tries))
        if request.request_id == self._probe:
            self._probe = None
        if request.request_id == self._resync_request:
            self._resync_request = None
            setting = (request.param, request.channel, request.value)
            if outcome is Outcome.FAIL_LINK:
                # The board went silent (or its port): paused, not given up. It goes on
                # when the board is heard going on (restarted again meanwhile, it starts
                # over), with its rounds afresh: a silence is not an unanswered board.
                self._resync_rounds = 0
                self._requeue(setting)
            elif outcome is Outcome.FAIL_TIMEOUT and self._resync_rounds < _RESYNC_ROUNDS:
                # Unanswered is not refused: asked again at once, so an answer that comes
                # late (a loaded machine, a slow line) confirms the new request.
                self._resync_rounds += 1
                self._requeue(setting)
                self._resync_next(now)
            else:
                self._resync_rounds = 0
                self._resync_failed.append((request.param.full_name(request.channel), error))
                self._resync_next(now)

    def _requeue(self, setting: tuple[Param, int, int | float | None]) -> None:
        param, channel, value = setting
        if self._resync is not None and value is not None:
            self._resync.appendleft((param, channel, value))

    def _done(self, request: _Request, value: int | float, now: float) -> None:
        """A request confirmed ``value``: the configuration held, the telemetry expected,
        a probe's answer, the resync's next step."""
        param, channel = request.param, request.channel
        if request.value is not None:
            # Keys keep their first place: the order the configuration was built in.
            self.held[(param.id, channel)] = (param, channel, value)
            self._unconfirmed.pop((param.id, channel), None)
        self._confirmed(param, channel, value, now)
        if request.request_id == self._probe:
            self._probe = None
            held = self.held.get((param.id, channel))
            # A set of this parameter left unconfirmed (asked again meanwhile, say, or
            # still waiting behind the telemetry in a slow host's port) may have been
            # applied: reading its value is no lost configuration. (A robot quieting a
            # board found streaming was taken for a restarted board, and the resync set
            # the telemetry on again.)
            if held is not None and held[2] != value \
                    and value not in self._unconfirmed.get((param.id, channel), ()):
                self._restarted(RestartEvidence.CONFIG_LOST,
                                f"{param.full_name(channel)} reads {value} on the board; "
                                f"this host set {held[2]}", now)
            elif self._verify is not None:
                self._back()
        elif request.request_id == self._resync_request:
            self._resync_applied += 1
            self._resync_rounds = 0
            self._resync_next(now)

    def _settle_all(self, error: FpgalinkError) -> None:
        for request in list(self._requests.values()):
            self._settle(request, Answer.LINK_DOWN, 0.0, error=error)
        self._probe = None

    @property
    def pending_requests(self) -> int:
        return len(self._requests)


