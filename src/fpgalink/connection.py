"""The sans-I/O link: bytes in, events out; requests in, bytes out; time passed in.

Modelled on h11 and aioquic. Nothing here reads a clock, opens a port or imports asyncio:
the caller passes ``now`` (seconds, any monotonic origin) and drives

* ``receive_data(data, now)`` then ``next_event()`` until it returns ``None``;
* ``send(message)`` → bytes to write, and ``data_to_send()`` for bytes the link itself
  produced (heartbeats, resends);
* ``get_timer()`` → when to call ``handle_timer(now)`` next.

Bad input from the board never raises: it is an event (:class:`Malformed`,
:class:`NoiseDropped`, :class:`FrameAborted`, :class:`CounterGap` …) and a counter in
:attr:`Connection.stats`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field, fields
from enum import Enum
from typing import Any

from fpgalink._counter import CounterTracker, Observation, SendCounter
from fpgalink._framing import (
    DEFAULT_FRAMING,
    AbortReason,
    FrameAborted,
    FrameDecoder,
    Framing,
    FramingError,
    NoiseDropped,
    encode_frame,
)
from fpgalink._messages import (
    ALIVE,
    DISABLE,
    ENABLE,
    Alive,
    CountedMessage,
    DirectCommand,
    Disable,
    Enable,
    Malformed,
)
from fpgalink._state import EnableState, Liveness, LivenessInput, next_liveness
from fpgalink.catalogue import (
    Message,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    References,
    Telemetry,
    encode_message,
    parse_content,
)
from fpgalink.errors import (
    BoardLost,
    FpgalinkError,
    LinkClosed,
    LocalProtocolError,
    ParameterRefused,
    RequestTimeout,
)
from fpgalink.params import Param, ParamType, float32

__all__ = [
    "BoardFound",
    "BoardSilent",
    "Connection",
    "CounterDuplicate",
    "CounterGap",
    "CounterLate",
    "EventsDropped",
    "LinkStats",
    "RequestDone",
    "RequestFailed",
    "Role",
]


class Role(Enum):
    HOST = "host"
    BOARD = "board"


_SENT_BY = {
    Role.HOST: (ParamSet, ParamGet, References, Enable, Disable, CountedMessage),
    Role.BOARD: (ParamAck, ParamNack, Telemetry, Alive, CountedMessage),
}


# --- events beyond the messages themselves ----------------------------------------------------


@dataclass(frozen=True, slots=True)
class CounterGap:
    """Counters were skipped before ``counter``: ``lost`` messages never arrived (so far)."""

    lost: int
    counter: int


@dataclass(frozen=True, slots=True)
class CounterDuplicate:
    counter: int


@dataclass(frozen=True, slots=True)
class CounterLate:
    """A message reported missing arrived after all (reordered on the way)."""

    counter: int


@dataclass(frozen=True, slots=True)
class BoardSilent:
    """Nothing well-formed heard for longer than the liveness timeout: the board is lost."""

    silent_for: float


@dataclass(frozen=True, slots=True)
class BoardFound:
    """The board is heard again after being lost (or for the first time)."""


@dataclass(frozen=True, slots=True)
class EventsDropped:
    """The caller did not drain events and the queue hit its cap; the oldest were dropped."""

    count: int


@dataclass(frozen=True, slots=True)
class RequestDone:
    """A parameter request was confirmed: ``value`` is what the board says is in force."""

    request_id: int
    param: Param
    channel: int
    value: int | float
    tries: int


@dataclass(frozen=True, slots=True)
class RequestFailed:
    request_id: int
    param: Param
    channel: int
    error: FpgalinkError
    tries: int


Event = Any  # messages, framing errors and the dataclasses above; see docs/protocol.md


@dataclass(slots=True)
class LinkStats:
    """Everything the link counted. Plain integers, cheap to read; ``snapshot()`` copies."""

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
    heartbeats_sent: int = 0
    heartbeat_misses: int = 0  #: times the board went silent past the liveness timeout
    events_dropped: int = 0
    subscriber_drops: int = 0  #: telemetry samples a slow subscriber lost (asyncio layer)
    port_losses: int = 0
    reconnects: int = 0
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


@dataclass(slots=True)
class _Request:
    request_id: int
    param: Param
    channel: int
    value: int | float | None  #: None for a get
    deadline: float
    tries: int
    message: ParamSet | ParamGet


def _same_value(param: Param, a: float, b: float) -> bool:
    if param.type is ParamType.FLOAT:
        return float32(a) == float32(b) or (math.isnan(a) and math.isnan(b))
    return int(a) == int(b)


class Connection:
    """One link to one board (or, with ``role=Role.BOARD``, the board's side of it)."""

    def __init__(
        self,
        role: Role = Role.HOST,
        *,
        framing: Framing = DEFAULT_FRAMING,
        heartbeat_interval: float = 0.1,
        liveness_timeout: float = 0.7,
        request_timeout: float = 0.05,
        request_tries: int = 8,
        max_events: int = 65536,
    ) -> None:
        if not 0 < heartbeat_interval < 0.3:
            raise ValueError(
                f"heartbeat_interval must be below the board's 300 ms watchdog, got "
                f"{heartbeat_interval!r} s"
            )
        if request_tries < 1 or request_timeout <= 0 or liveness_timeout <= 0:
            raise ValueError("request_tries ≥ 1 and positive timeouts are required")
        self.role = role
        self.framing = framing
        self.heartbeat_interval = heartbeat_interval
        self.liveness_timeout = liveness_timeout
        self.request_timeout = request_timeout
        self.request_tries = request_tries
        self.stats = LinkStats()
        self.counter_tracker = CounterTracker()
        self._decoder = FrameDecoder(framing)
        self._send_counter = SendCounter()
        self._events: deque[Event] = deque()
        self._max_events = max_events
        self._outbox = bytearray()
        self.liveness = Liveness.UNKNOWN
        self.enable_state = EnableState.DISABLED
        self._last_heard: float | None = None
        self._liveness_origin: float | None = None
        self._next_heartbeat: float | None = None
        self._requests: dict[int, _Request] = {}
        self._next_request_id = 1
        self.latest_telemetry: Telemetry | None = None

    # --- receiving ------------------------------------------------------------------------

    def receive_data(self, data: bytes | bytearray | memoryview, now: float | None = None) -> None:
        """Feed bytes from the wire. ``now`` (if given) dates the arrival for liveness."""
        stats = self.stats
        stats.bytes_received += len(data)
        events = self._events
        append = events.append
        tracker = self.counter_tracker
        frames = telemetry = counted = 0
        latest: Telemetry | None = None
        heard = False
        for item in self._decoder.feed(data):
            if type(item) is not bytes:
                self._framing_event(item)  # type: ignore[arg-type]
                continue
            frames += 1
            msg = parse_content(item)
            kind = type(msg)
            if kind is Telemetry:
                # The 1 kHz path: no attribute lookups beyond the counter check.
                telemetry += 1
                latest = msg  # type: ignore[assignment]
                counter = msg.counter  # type: ignore[union-attr]
            elif kind is Malformed:
                stats.malformed += 1
                key = msg.reason.name  # type: ignore[union-attr]
                stats.malformed_by_reason[key] = stats.malformed_by_reason.get(key, 0) + 1
                append(msg)
                continue
            else:
                heard = True
                counter = getattr(msg, "counter", None)
                if counter is None:  # a direct command
                    if msg is ALIVE:
                        stats.alive_received += 1
                    append(msg)
                    continue
                if kind is ParamAck or kind is ParamNack:
                    self._match_request(msg, now)  # type: ignore[arg-type]
            counted += 1
            if tracker.expected == counter:
                tracker.expected = counter + 1 if counter != 99_999 else 0  # type: ignore[operator]
                tracker.received += 1
            else:
                self._counter_event(tracker.observe(counter), counter)  # type: ignore[arg-type]
            append(msg)
        stats.frames_received += frames
        stats.messages_received += counted
        if telemetry:
            heard = True
            stats.telemetry_received += telemetry
            self.latest_telemetry = latest
        if heard and now is not None:
            self._heard(now)
        if len(events) > self._max_events:
            excess = len(events) - self._max_events
            for _ in range(excess):
                events.popleft()
            stats.events_dropped += excess
            events.append(EventsDropped(excess))

    def _framing_event(self, item: FramingError) -> None:
        stats = self.stats
        if isinstance(item, NoiseDropped):
            stats.noise_bytes += item.dropped
        elif isinstance(item, FrameAborted):
            if item.reason is AbortReason.OVERFLOW:
                stats.overflows += 1
            else:
                stats.aborted_frames += 1
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
        while self._events:
            yield self._events.popleft()

    @property
    def pending_events(self) -> int:
        return len(self._events)

    # --- sending --------------------------------------------------------------------------

    def send(self, message: Message | CountedMessage | DirectCommand) -> bytes:
        """Wire bytes for ``message``; a counted message takes the next counter value."""
        if not isinstance(message, _SENT_BY[self.role]):
            raise LocalProtocolError(
                f"a {self.role.value} does not send {type(message).__name__}"
            )
        if isinstance(message, DirectCommand):
            content = message.content
        else:
            content = encode_message(message, self._send_counter.take())
        wire = encode_frame(content, self.framing)
        self.stats.frames_sent += 1
        self.stats.bytes_sent += len(wire)
        return wire

    def reset_receiver(self) -> None:
        """Drop any half-received frame (after a reconnect the stream starts afresh)."""
        self._decoder.reset()

    def data_to_send(self) -> bytes:
        """Bytes the link produced on its own (heartbeats, request resends)."""
        out = bytes(self._outbox)
        self._outbox.clear()
        return out

    def _queue(self, message: Message | DirectCommand) -> None:
        self._outbox += self.send(message)

    @property
    def next_counter(self) -> int:
        return self._send_counter.value

    # --- heartbeat and liveness -----------------------------------------------------------

    def enable(self, now: float) -> None:
        """Send ``RE`` now and every ``heartbeat_interval`` until :meth:`disable`."""
        self.enable_state = EnableState.ENABLED
        self._heartbeat(now)

    def disable(self, now: float) -> None:
        """Stop the heartbeat and send ``RD`` (the board drops enable at once)."""
        self.enable_state = EnableState.DISABLED
        self._next_heartbeat = None
        self._queue(DISABLE)

    def _heartbeat(self, now: float) -> None:
        self._queue(ENABLE)
        self.stats.heartbeats_sent += 1
        self._next_heartbeat = now + self.heartbeat_interval

    def start_liveness(self, now: float) -> None:
        """Begin expecting the board: silence from ``now`` on counts."""
        self._liveness_origin = now

    def _heard(self, now: float) -> None:
        self._last_heard = now
        before = self.liveness
        self.liveness = next_liveness(before, LivenessInput.HEARD)
        if before is not Liveness.ALIVE:
            self._events.append(BoardFound())

    def get_timer(self) -> float | None:
        """The next time :meth:`handle_timer` has work to do, or ``None``."""
        deadlines = [r.deadline for r in self._requests.values()]
        if self._next_heartbeat is not None:
            deadlines.append(self._next_heartbeat)
        silence = self._silence_deadline()
        if silence is not None:
            deadlines.append(silence)
        return min(deadlines) if deadlines else None

    def _silence_deadline(self) -> float | None:
        if self.liveness is Liveness.LOST:
            return None
        origin = self._last_heard if self._last_heard is not None else self._liveness_origin
        return None if origin is None else origin + self.liveness_timeout

    def handle_timer(self, now: float) -> None:
        if self._next_heartbeat is not None and now >= self._next_heartbeat:
            self._heartbeat(now)
        silence = self._silence_deadline()
        if silence is not None and now >= silence:
            origin = self._last_heard if self._last_heard is not None else self._liveness_origin
            assert origin is not None
            self.liveness = next_liveness(self.liveness, LivenessInput.SILENT)
            self.stats.heartbeat_misses += 1
            self._events.append(BoardSilent(now - origin))
            self.fail_requests(BoardLost(f"board silent for {now - origin:.3f} s"))
        for request in list(self._requests.values()):
            if now >= request.deadline:
                if request.tries >= self.request_tries:
                    del self._requests[request.request_id]
                    what = (
                        f"set {request.param.full_name(request.channel)}"
                        if request.value is not None
                        else f"get {request.param.full_name(request.channel)}"
                    )
                    self._events.append(
                        RequestFailed(
                            request.request_id, request.param, request.channel,
                            RequestTimeout(what, request.tries, self.request_timeout),
                            request.tries,
                        )
                    )
                else:
                    self._resend(request, now)

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
        self._queue(message)
        return request_id

    def _resend(self, request: _Request, now: float) -> None:
        request.tries += 1
        request.deadline = now + self.request_timeout
        self.stats.retries += 1
        self._queue(request.message)

    def _match_request(self, msg: ParamAck | ParamNack, now: float | None) -> None:
        for request in self._requests.values():
            if request.param.id != msg.param_id or request.channel != msg.channel:
                continue
            if isinstance(msg, ParamNack):
                del self._requests[request.request_id]
                error = ParameterRefused(
                    request.param.full_name(request.channel), msg.channel, msg.reason, msg.error
                )
                self._events.append(
                    RequestFailed(request.request_id, request.param, request.channel, error,
                                  request.tries)
                )
                return
            if request.value is None or _same_value(request.param, request.value, msg.value):
                del self._requests[request.request_id]
                self._events.append(
                    RequestDone(request.request_id, request.param, request.channel, msg.value,
                                request.tries)
                )
                return
            # An echo with another value (an older request's, or a lost PS): try again now.
            if request.tries < self.request_tries:
                self._resend(request, now if now is not None else request.deadline)
            return

    def fail_requests(self, error: FpgalinkError) -> None:
        """Fail every pending request with ``error`` (board lost, link closed)."""
        for request in list(self._requests.values()):
            self._events.append(
                RequestFailed(request.request_id, request.param, request.channel, error,
                              request.tries)
            )
        self._requests.clear()

    def close(self) -> None:
        self._next_heartbeat = None
        self.enable_state = EnableState.DISABLED
        self.fail_requests(LinkClosed("link closed while the request was pending"))

    @property
    def pending_requests(self) -> int:
        return len(self._requests)
