"""The asyncio link: a thin layer over the sans-I/O :class:`~fpgalink.Connection`.

Shaped like aioquic's protocol: a :class:`Link` is handed its connection and a transport.
It feeds received bytes to the connection, writes what the connection produces, arms one
loop timer at ``Connection.get_timer()``, and turns events into futures (one per pending
request), telemetry subscriptions and link events. Every protocol decision and every count
lives in the connection; the link only moves bytes and wakes waiters.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass
from enum import Enum
from types import TracebackType
from typing import Any, Generic, NamedTuple, TypeVar

from fpgalink.aio.transport import (
    FAR_END_LAG_EXTRA,
    READ_CHUNK,
    ProtocolFactory,
    open_transport,
)
from fpgalink.connection import Connection, LinkStats, Liveness
from fpgalink.errors import BoardLost, FpgalinkError, LinkClosed, PortError
from fpgalink.events import (
    BoardBack,
    BoardFault,
    BoardFound,
    BoardRestarted,
    BoardResynced,
    BoardSilent,
    RequestDone,
    RequestFailed,
    TelemetryResumed,
    TelemetryStale,
    WatchdogLapsed,
)
from fpgalink.protocol import (
    DEFAULT_FRAMING,
    CountedMessage,
    DirectCommand,
    Event,
    Framing,
    Message,
    Param,
    References,
    Telemetry,
    resolve,
)
from fpgalink.protocol.params import iter_addresses

__all__ = [
    "Link",
    "LinkEvent",
    "LinkEventKind",
    "LinkState",
    "Reopen",
    "Stamped",
    "Subscription",
    "SyncResult",
    "open_link",
]

T = TypeVar("T")

#: A timer armed against a far end that has fallen behind comes no sooner than this: the far
#: end runs on this loop and needs the turn to catch up.
_MIN_REARM_S = 0.0005
#: While the far end trails, a timer is looked at again within this, its lag measured anew.
_LAGGING_RECHECK_S = 0.002

#: Opens a transport to the board (again, after the port vanished), given the protocol.
Reopen = Callable[[ProtocolFactory], Awaitable[tuple[asyncio.BaseTransport, asyncio.Protocol]]]


class Stamped(NamedTuple):
    """A telemetry sample and when the link received it (the loop's clock, seconds)."""

    at: float
    sample: Telemetry


class LinkState(Enum):
    CONNECTING = "connecting"
    CONNECTED = "connected"
    RECONNECTING = "reconnecting"  #: the port vanished; retrying with backoff
    CLOSED = "closed"


class LinkEventKind(Enum):
    BOARD_LOST = "board_lost"  #: no well-formed message for ``liveness_timeout``
    BOARD_FOUND = "board_found"
    #: the board restarted (or may have); the link stopped enabling it and sets again what
    #: it holds (:class:`~fpgalink.events.BoardRestarted`)
    BOARD_RESTARTED = "board_restarted"
    #: after a restart, what the link holds is set again (detail: what failed, if anything)
    BOARD_RESYNCED = "board_resynced"
    #: heard again after a silence (or on a reconnected port), it did not restart
    BOARD_BACK = "board_back"
    #: the board's watchdog disabled it; the link stopped enabling it
    WATCHDOG_LAPSED = "watchdog_lapsed"
    TELEMETRY_STALE = "telemetry_stale"  #: configured on, and not arriving
    TELEMETRY_RESUMED = "telemetry_resumed"
    PORT_LOST = "port_lost"  #: the device or socket went away
    PORT_RESTORED = "port_restored"
    CLOSED = "closed"  #: the link closed: the last event a watcher gets


@dataclass(frozen=True, slots=True)
class LinkEvent:
    kind: LinkEventKind
    at: float  #: loop time
    detail: str = ""
    #: the connection's event behind it, where there is one (BoardRestarted, …)
    cause: Event | None = None


@dataclass(frozen=True, slots=True)
class SyncResult:
    """One line of :meth:`Link.sync_params`: confirmed value or the error."""

    name: str
    requested: int | float
    confirmed: int | float | None
    error: FpgalinkError | None

    @property
    def ok(self) -> bool:
        return self.error is None


class Subscription(Generic[T]):
    """``async for item in sub`` over a bounded queue that drops its oldest item when full
    (counting the drop) and ends when the link closes or :meth:`close` is called. The link
    never waits for a subscriber."""

    def __init__(self, maxsize: int, on_close: Callable[[Subscription[T]], None]) -> None:
        if maxsize < 1:
            raise ValueError("maxsize must be at least 1")
        self._items: deque[T] = deque(maxlen=maxsize)
        self._ready = asyncio.Event()
        self._closed = False
        self._on_close = on_close
        self.dropped = 0

    def _push(self, item: T) -> bool:
        """Queue ``item``; ``True`` when the oldest had to go to make room."""
        dropped = len(self._items) == self._items.maxlen
        if dropped:
            self.dropped += 1
        self._items.append(item)
        self._ready.set()
        return dropped

    def _end(self) -> None:
        self._closed = True
        self._ready.set()

    def close(self) -> None:
        self._on_close(self)
        self._end()

    def __aiter__(self) -> Subscription[T]:
        return self

    async def __anext__(self) -> T:
        while not self._items:
            if self._closed:
                raise StopAsyncIteration
            self._ready.clear()
            await self._ready.wait()
        return self._items.popleft()

    def __len__(self) -> int:
        return len(self._items)

    async def __aenter__(self) -> Subscription[T]:
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()


class _PortProtocol(asyncio.Protocol):
    """The link's end of one transport. A new one per (re)connection, so a late callback
    from a transport already replaced is recognised and ignored."""

    def __init__(self, link: Link) -> None:
        self._link = link

    def data_received(self, data: bytes) -> None:
        self._link._on_data(self, data)

    def connection_lost(self, exc: Exception | None) -> None:
        self._link._on_port_lost(self, exc)


class Link:
    """One board. Use ``async with open_link(url) as link:`` so it always closes.

    ``Link(connection, transport)`` attaches to a transport already open (a test's
    :class:`~fpgalink.testing.MemoryTransport`, say). With ``reopen`` and no transport,
    :meth:`open` opens one, and with ``reconnect`` the link reopens it with backoff when the
    port vanishes; :func:`open_link` builds all of that from a URL."""

    def __init__(
        self,
        connection: Connection,
        transport: asyncio.BaseTransport | None = None,
        *,
        name: str = "board",
        url: str = "",
        reopen: Reopen | None = None,
        reconnect: bool = True,
        reconnect_backoff: tuple[float, float] = (0.05, 2.0),
    ) -> None:
        self.connection = connection
        self.name = name
        self.url = url  #: where the board is, for messages
        self.reconnect = reconnect and reopen is not None
        self.reconnect_backoff = reconnect_backoff
        #: a parameter request left unanswered after its tries while the board is heard
        #: is asked again at once this many more times (a late answer then confirms the
        #: request asked after it: a loaded machine, a slow line); 0: it fails at once
        self.unanswered_rounds = 0
        self.state = LinkState.CONNECTING
        self._reopen = reopen
        self._transport: asyncio.BaseTransport | None = None
        self._protocol: _PortProtocol | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._timer_at: float | None = None  #: on the link's time (:meth:`_now`)
        self._far_end_lag: Callable[[], float] | None = None
        self._last_now = -math.inf
        self._futures: dict[int, asyncio.Future[int | float]] = {}
        self._telemetry_subs: set[Subscription[Telemetry]] = set()
        self._stamped_subs: set[Subscription[Stamped]] = set()
        self._event_subs: set[Subscription[LinkEvent]] = set()
        self._listeners: list[Callable[[Event], None]] = []
        self._event_callbacks: list[Callable[[LinkEvent], None]] = []
        self._reconnect_task: asyncio.Task[None] | None = None
        self._port_released: asyncio.Event | None = None
        #: gather received bytes for up to this long (see :meth:`set_read_latency`)
        self.read_latency: float | None = None
        self._read_pause: asyncio.TimerHandle | None = None
        if transport is not None:
            self._attach(transport)

    # --- lifecycle ------------------------------------------------------------------------

    def _protocol_factory(self) -> _PortProtocol:
        self._protocol = _PortProtocol(self)
        return self._protocol

    def _attach(self, transport: asyncio.BaseTransport) -> None:
        transport.set_protocol(self._protocol_factory())
        self._set_transport(transport)

    async def _connect(self) -> None:
        if self._reopen is None:
            raise PortError(f"{self.name}: no transport and nothing to open one with")
        transport, _ = await self._reopen(self._protocol_factory)
        self._set_transport(transport)

    def _set_transport(self, transport: asyncio.BaseTransport) -> None:
        self._transport = transport
        lag = transport.get_extra_info(FAR_END_LAG_EXTRA)
        self._far_end_lag = lag if callable(lag) else None
        self.connection.boards_time = self._far_end_lag is not None

    async def open(self) -> Link:
        """Connect (unless a transport was given) and start expecting the board."""
        self._loop = asyncio.get_running_loop()
        if self._transport is None:
            await self._connect()
        self.state = LinkState.CONNECTED
        self.connection.start(self._now())
        self._arm_timer()
        return self

    async def close(self) -> None:
        """Send ``RD`` if enabled, fail pending requests with :class:`LinkClosed`, end every
        subscription and watcher, release the port. Safe to call twice."""
        if self.state is LinkState.CLOSED:
            self._end_waiters()
            return
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
        connected = self.state is LinkState.CONNECTED
        self.state = LinkState.CLOSED
        self.connection.close(self._now())
        if connected:
            self._write(self.connection.data_to_send())
        if self._reconnect_task is not None:
            self._reconnect_task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._reconnect_task
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._read_pause is not None:
            self._read_pause.cancel()
            self._read_pause = None
        self._process()
        self._emit(LinkEventKind.CLOSED)
        self._end_waiters()
        transport, self._transport = self._transport, None
        if transport is not None:
            # Wait until the transport says it is gone (it may first flush the RD just
            # written): only then is the port released and can be opened again.
            self._port_released = asyncio.Event()
            transport.close()
            try:
                await asyncio.wait_for(self._port_released.wait(), 1.0)
            except TimeoutError:
                abort = getattr(transport, "abort", None)
                if abort is not None:
                    abort()
                await asyncio.sleep(0)

    def _end_waiters(self) -> None:
        for future in self._futures.values():
            if not future.done():
                future.set_exception(LinkClosed(f"{self.name}: link closed"))
        self._futures.clear()
        for telemetry_sub in self._telemetry_subs:
            telemetry_sub._end()
        for stamped_sub in self._stamped_subs:
            stamped_sub._end()
        for event_sub in self._event_subs:
            event_sub._end()
        self._telemetry_subs.clear()
        self._stamped_subs.clear()
        self._event_subs.clear()

    async def __aenter__(self) -> Link:
        return await self.open()

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    # --- commands -------------------------------------------------------------------------

    def enable(self) -> None:
        """Send ``RE`` now and every heartbeat interval until :meth:`disable` or close."""
        self._ensure_connected()
        self.connection.enable(self._now())
        self._flush()

    def disable(self) -> None:
        """Stop the heartbeat and send ``RD``: the board disables at once."""
        self._ensure_open()
        self.connection.disable(self._now())
        self._flush()

    def resync(self) -> None:
        """Set again every parameter this link holds, as after a restart (done by itself
        then): for a resync that failed for want of answers. ``BOARD_RESYNCED`` says how it
        went."""
        self._ensure_connected()
        self.connection.resync(self._now())
        self._flush()

    @property
    def enabled(self) -> bool:
        return self.connection.enabled

    def set_references(self, ref_a: float, ref_b: float) -> None:
        """Send ``RV`` (deg/s in speed control, N·m in torque control). Non-finite values
        raise :class:`~fpgalink.errors.LocalProtocolError` and nothing is sent; when the
        line is backed up, a newer reference replaces one still waiting (counted in
        ``stats.references_superseded``)."""
        self.send(References(float(ref_a), float(ref_b)))

    def send(self, message: Message | CountedMessage | DirectCommand) -> bytes:
        """Send any message; returns the exact wire bytes written (empty when a reference
        waits for line room)."""
        self._ensure_connected()
        self.connection.send(message, self._now())
        wire = self.connection.data_to_send()
        self._write(wire)
        self._arm_timer()
        return wire

    async def set_param(
        self, name: str | int, value: object, channel: int | str | None = None
    ) -> int | float:
        """Set a parameter and return the value the board confirms is in force.

        Raises :class:`~fpgalink.errors.ParameterError` before sending for a bad name,
        channel, type or range; :class:`~fpgalink.errors.ParameterRefused` on ``PN``;
        :class:`~fpgalink.errors.ValueMismatch` when the board kept echoing another value;
        :class:`~fpgalink.errors.RequestTimeout` when every try went unanswered."""
        param, code = resolve(name, channel)
        coerced = param.coerce(value)
        self._ensure_connected()
        return await self._patiently(
            lambda: self.connection.set_param(param, code, coerced, self._now()))

    async def get_param(self, name: str | int, channel: int | str | None = None) -> int | float:
        param, code = resolve(name, channel)
        self._ensure_connected()
        return await self._patiently(lambda: self.connection.get_param(param, code, self._now()))

    async def _patiently(self, ask: Callable[[], int]) -> int | float:
        return await self._request(ask())

    async def read_params(self, *, hold: bool = False) -> dict[tuple[int, int], int | float]:
        """Every parameter address's value, ``{(param id, channel): value}``, in table order;
        stops at the first failure (a silent board would otherwise cost every address its
        full retry budget). ``hold``: keep what the board runs now as this link's
        configuration, set again if the board restarts (:attr:`held`)."""
        values: dict[tuple[int, int], int | float] = {}
        for param, code in iter_addresses():
            values[(param.id, code)] = value = await self.get_param(param.id, code)
            if hold:
                self.connection.hold(param, code, value)
        return values

    async def sync_params(
        self, values: Mapping[str, object] | Iterable[tuple[str, str | None, object]]
    ) -> list[SyncResult]:
        """Set many parameters, one at a time (the board's RX RAM holds two frames), and
        report each: keys are ``"Kp_Wheel_PidA"`` style names, or give
        ``(name, channel, value)`` triples. Host-side validation happens for all of them
        before the first byte is sent."""
        items: list[tuple[Param, int, int | float]] = []
        entries = (
            [(k, None, v) for k, v in values.items()] if isinstance(values, Mapping)
            else list(values)
        )
        for name, channel, value in entries:
            param, code = resolve(name, channel)
            items.append((param, code, param.coerce(value)))
        results: list[SyncResult] = []
        for param, code, coerced in items:
            label = param.full_name(code)
            try:
                self._ensure_connected()
                confirmed = await self._request(
                    self.connection.set_param(param, code, coerced, self._now())
                )
                results.append(SyncResult(label, coerced, confirmed, None))
            except FpgalinkError as exc:
                results.append(SyncResult(label, coerced, None, exc))
        return results

    async def _request(self, request_id: int) -> int | float:
        assert self._loop is not None
        future: asyncio.Future[int | float] = self._loop.create_future()
        self._futures[request_id] = future
        self._resume_reading()  # its answer must not wait for a batch
        self._flush()
        try:
            return await future
        finally:
            self._futures.pop(request_id, None)

    # --- telemetry and events -------------------------------------------------------------

    def telemetry(self, maxsize: int = 1024) -> Subscription[Telemetry]:
        """A new independent subscriber. When its queue is full the oldest sample is dropped
        and counted (``sub.dropped``, ``link.stats.subscriber_drops``); the link never waits."""
        sub: Subscription[Telemetry] = Subscription(maxsize, self._telemetry_subs.discard)
        if self.state is LinkState.CLOSED:
            sub._end()
        else:
            self._telemetry_subs.add(sub)
        return sub

    def stamped_telemetry(self, maxsize: int = 1024) -> Subscription[Stamped]:
        """As :meth:`telemetry`, each sample with the loop time the link received it — the
        host's side of the clock, beside the board's ``t_us``."""
        sub: Subscription[Stamped] = Subscription(maxsize, self._stamped_subs.discard)
        if self.state is LinkState.CLOSED:
            sub._end()
        else:
            self._stamped_subs.add(sub)
        return sub

    def watch(self, maxsize: int = 256) -> AsyncIterator[LinkEvent]:
        """Link events (board lost/found, port lost/restored) as an async iterator; it ends
        after the ``CLOSED`` event when the link closes, for whatever reason."""
        sub: Subscription[LinkEvent] = Subscription(maxsize, self._event_subs.discard)
        if self.state is LinkState.CLOSED:
            sub._end()
        else:
            self._event_subs.add(sub)
        return sub

    def on_event(self, callback: Callable[[LinkEvent], None]) -> Callable[[], None]:
        """Call ``callback(event)`` for every link event, synchronously, as it happens: for
        reactions that must not wait for a task to be scheduled (a robot stopping its other
        boards when one goes silent). Keep it quick and do not raise. Returns a remover."""
        self._event_callbacks.append(callback)

        def remove() -> None:
            if callback in self._event_callbacks:
                self._event_callbacks.remove(callback)

        return remove

    def add_listener(self, listener: Callable[[Event], None]) -> Callable[[], None]:
        """Call ``listener(event)`` with everything the connection reports, in order: every
        received message (catalogued, generic, direct commands), ``Malformed``, framing
        errors, counter gaps, request outcomes… Returns a function that removes it.
        Listeners run inside the receive path: keep them quick and do not raise."""
        self._listeners.append(listener)

        def remove() -> None:
            if listener in self._listeners:
                self._listeners.remove(listener)

        return remove

    @property
    def latest(self) -> Telemetry | None:
        """The newest telemetry sample, or ``None`` before the first."""
        return self.connection.latest_telemetry

    @property
    def stats(self) -> LinkStats:
        return self.connection.stats

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        """What the transport offers under ``name`` (asyncio's ``get_extra_info``): for
        example an emulated robot's true pose (``"fpgaemu.truth"``). ``default`` while no
        transport is attached."""
        transport = self._transport
        return default if transport is None else transport.get_extra_info(name, default)

    @property
    def board_alive(self) -> bool:
        return self.connection.liveness is Liveness.ALIVE

    @property
    def held(self) -> dict[str, int | float]:
        """Every parameter set on this link and confirmed by the board (``"Kp_Wheel_PidA"``
        style names, in the order first set): what is set again if the board restarts."""
        return {param.full_name(channel): value
                for param, channel, value in self.connection.held.values()}

    @property
    def resyncing(self) -> bool:
        """The board restarted and what this link holds is being set again."""
        return self.connection.resyncing

    # --- plumbing -------------------------------------------------------------------------

    def _now(self) -> float:
        """The link's time: the loop's clock, less how far an in-process far end trails it
        (:data:`~fpgalink.aio.transport.FAR_END_LAG_EXTRA`); never going back."""
        assert self._loop is not None
        now = self._loop.time()
        lag = self._far_end_lag
        if lag is not None:
            now -= lag()
        if now < self._last_now:
            return self._last_now
        self._last_now = now
        return now

    def _ensure_open(self) -> None:
        if self.state is LinkState.CLOSED:
            raise LinkClosed(f"{self.name}: link is closed")
        if self._loop is None:
            raise LinkClosed(f"{self.name}: link is not open yet (use `async with`)")

    def _ensure_connected(self) -> None:
        self._ensure_open()
        if self.state is not LinkState.CONNECTED or self._transport is None:
            raise BoardLost(f"{self.name}: port is disconnected ({self.state.value})")

    def _write(self, data: bytes) -> None:
        if data and self._transport is not None and self.state is not LinkState.RECONNECTING:
            self._transport.write(data)  # type: ignore[attr-defined]

    def _on_data(self, protocol: _PortProtocol, data: bytes) -> None:
        if protocol is not self._protocol or self.state is not LinkState.CONNECTED:
            return
        self.connection.receive_data(data, self._now())
        self._process()
        self._flush()
        if self.read_latency and not self._futures and self._read_pause is None:
            self._pause_reading()

    # --- read batching --------------------------------------------------------------------

    def set_read_latency(self, seconds: float | None) -> None:
        """Let the link gather received bytes for up to ``seconds`` before handling them
        (``None`` or 0: handle every read at once, the default). For a consumer that needs
        samples at 100 Hz or less: at 1 kHz telemetry a 10 ms bound turns a thousand
        wake-ups a second into about a hundred, losing nothing. A pending parameter request
        is never held back: reading resumes at once while one is in flight."""
        if seconds is not None and not (math.isfinite(seconds) and 0 <= seconds <= 1.0):
            raise ValueError(f"read latency must be 0..1 s, got {seconds!r}")
        self.read_latency = seconds or None
        if self.read_latency is None:
            self._resume_reading()

    def _pause_reading(self) -> None:
        """Enter a batch: the loop stops watching the port; a timer collects what arrived
        when the bound is up (one wake-up and one read per batch)."""
        transport = self._transport
        pause = getattr(transport, "pause_reading", None)
        if pause is None or self._loop is None or self.read_latency is None:
            return
        try:
            pause()
        except (RuntimeError, AttributeError):  # closing, or not a reading transport
            return
        self._read_pause = self._loop.call_later(self.read_latency, self._collect_batch)

    def _collect_batch(self) -> None:
        self._read_pause = None
        data = _read_waiting(self._transport)
        if data is None:  # nothing to read it with, or the port has an error: let the
            self._resume_transport()  # transport read and report as usual
            return
        if data and self._protocol is not None:
            self._on_data(self._protocol, data)  # may start the next batch
        elif self.read_latency and not self._futures and self._loop is not None:
            self._read_pause = self._loop.call_later(self.read_latency, self._collect_batch)
            return
        if self._read_pause is None:
            self._resume_transport()

    def _resume_reading(self) -> None:
        handle, self._read_pause = self._read_pause, None
        if handle is None:
            return
        handle.cancel()
        # Bytes that arrived during the batch go first, in order, before the transport
        # reads again.
        data = _read_waiting(self._transport)
        if data and self._protocol is not None:
            self._on_data(self._protocol, data)
            handle, self._read_pause = self._read_pause, None
            if handle is not None:
                handle.cancel()
        self._resume_transport()

    def _resume_transport(self) -> None:
        resume = getattr(self._transport, "resume_reading", None)
        if resume is not None:
            with contextlib.suppress(RuntimeError, AttributeError):
                resume()

    def _flush(self) -> None:
        self._write(self.connection.data_to_send())
        self._arm_timer()

    def _arm_timer(self) -> None:
        if self._loop is None or self.state is LinkState.CLOSED:
            return
        deadline = self.connection.get_timer()
        if deadline is None:
            return
        # Every message heard pushes the liveness deadline later; re-arming on each read
        # would churn the loop's timer heap at 1 kHz. A timer already due no later than the
        # new deadline stays: when it fires early, handle_timer finds nothing to do and we
        # arm again for the real deadline.
        if self._timer is not None and self._timer_at is not None and self._timer_at <= deadline:
            return
        if self._timer is not None:
            self._timer.cancel()
        self._timer_at = deadline
        # The deadline is on the link's time; the loop's clock is ahead of it by the far
        # end's lag. When the lag grows meanwhile the timer comes early, finds nothing due
        # and is armed again.
        at = deadline
        if self._far_end_lag is not None:
            now = self._loop.time()
            lag = now - self._now()
            at = max(deadline + lag, now + _MIN_REARM_S)
            if lag > _MIN_REARM_S:
                # The lag shrinks as the far end catches up (the deadline then comes sooner
                # on the loop's clock than it looked): look again soon rather than late.
                at = min(at, now + _LAGGING_RECHECK_S)
        self._timer = self._loop.call_at(at, self._on_timer)

    def _on_timer(self) -> None:
        self._timer = None
        self._timer_at = None
        self.connection.handle_timer(self._now())
        self._process()
        self._flush()

    def _emit(self, kind: LinkEventKind, detail: str = "", cause: Event | None = None) -> None:
        event = LinkEvent(kind, self._now(), detail, cause)
        for callback in list(self._event_callbacks):
            callback(event)
        for sub in self._event_subs:
            sub._push(event)

    def _process(self) -> None:
        stats = self.connection.stats
        listeners = self._listeners
        stamped = self._stamped_subs
        now = self._now() if stamped else 0.0
        for event in self.connection.events():
            for listener in listeners:
                listener(event)
            kind = type(event)
            if kind is Telemetry:
                assert isinstance(event, Telemetry)
                for sub in self._telemetry_subs:
                    if sub._push(event):
                        stats.subscriber_drops += 1
                for stamped_sub in stamped:
                    if stamped_sub._push(Stamped(now, event)):
                        stats.subscriber_drops += 1
            elif kind is RequestDone or kind is RequestFailed:
                future = self._futures.get(event.request_id)  # type: ignore[attr-defined]
                if future is not None and not future.done():
                    if isinstance(event, RequestDone):
                        future.set_result(event.value)
                    else:
                        assert isinstance(event, RequestFailed)
                        future.set_exception(event.error)
            elif isinstance(event, BoardSilent):
                self._emit(LinkEventKind.BOARD_LOST, f"silent for {event.silent_for:.3f} s")
            elif kind is BoardFound:
                self._emit(LinkEventKind.BOARD_FOUND)
            elif isinstance(event, BoardFault):
                self._emit(_REPORTED[kind], event.describe(), event)

    def _on_port_lost(self, protocol: _PortProtocol, exc: Exception | None) -> None:
        if protocol is not self._protocol:
            return  # a transport we already let go of
        if self.state is LinkState.CLOSED:
            if self._port_released is not None:
                self._port_released.set()
            return
        self._transport = None
        self._protocol = None
        cause = str(exc or "closed by the other end")
        reason = f"{self.name}: port lost ({cause})"
        self.connection.port_lost(self._now(), reason)
        self._process()
        self._emit(LinkEventKind.PORT_LOST, cause)
        if self.reconnect:
            self.state = LinkState.RECONNECTING
            self._reconnect_task = asyncio.ensure_future(self._reconnect_loop())
        else:
            self.state = LinkState.CLOSED
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None
            self._emit(LinkEventKind.CLOSED, reason)
            self._end_waiters()

    async def _reconnect_loop(self) -> None:
        delay, ceiling = self.reconnect_backoff
        while self.state is LinkState.RECONNECTING:
            await asyncio.sleep(delay)
            delay = min(delay * 2, ceiling)
            try:
                await self._connect()
            except PortError:
                continue
            self.state = LinkState.CONNECTED
            self.connection.reconnected(self._now())
            self._flush()
            self._emit(LinkEventKind.PORT_RESTORED)
            return


#: The connection's events about the board's real life, and the link events they become.
_REPORTED: dict[type[Event], LinkEventKind] = {
    BoardRestarted: LinkEventKind.BOARD_RESTARTED,
    BoardResynced: LinkEventKind.BOARD_RESYNCED,
    BoardBack: LinkEventKind.BOARD_BACK,
    WatchdogLapsed: LinkEventKind.WATCHDOG_LAPSED,
    TelemetryStale: LinkEventKind.TELEMETRY_STALE,
    TelemetryResumed: LinkEventKind.TELEMETRY_RESUMED,
}


def _read_waiting(transport: asyncio.BaseTransport | None) -> bytes | None:
    """What a paused transport's port holds now, without blocking: a serial port's device
    or a socket, read directly; ``None`` when there is no such thing to read or reading it
    failed (the transport, resumed, then sees and reports the problem itself)."""
    if transport is None:
        return None
    port = transport.get_extra_info("serial")
    if port is not None:
        try:
            data: bytes = port.read(READ_CHUNK)
        except Exception:  # pyserial raises its own kinds: the port is in trouble
            return None
        return data
    sock = transport.get_extra_info("socket")
    if sock is not None:
        try:
            data = os.read(sock.fileno(), READ_CHUNK)  # asyncio's sockets are non-blocking
        except BlockingIOError:
            return b""
        except (OSError, ValueError):
            return None
        return data if data else None  # b"": the peer closed
    return None


def open_link(
    url: str = "emu://",
    baud: int = 1_000_000,
    *,
    name: str | None = None,
    framing: Framing = DEFAULT_FRAMING,
    heartbeat_interval: float = 0.1,
    liveness_timeout: float = 0.7,
    request_timeout: float = 0.05,
    request_tries: int = 8,
    max_reference_delay: float = 0.005,
    reconnect: bool = True,
    reconnect_backoff: tuple[float, float] = (0.05, 2.0),
    read_latency: float | None = None,
    heartbeat_give_up: float = 0.28,
    stale_periods: int = 50,
    unanswered_rounds: int = 0,
) -> Link:
    """``async with open_link("/dev/ttyUSB0") as link:`` — a device path,
    ``socket://host:port``, or ``emu://`` for an emulated board in this process (any scheme
    a package registers). The connection settings go to :class:`~fpgalink.Connection`;
    ``reconnect`` reopens the URL with backoff when the port vanishes; ``read_latency``
    lets the link batch reads (:meth:`Link.set_read_latency`); ``heartbeat_give_up`` and
    ``stale_periods``: when a late heartbeat is not sent, and how many timer periods
    without telemetry are a fault (:class:`~fpgalink.Connection`); ``unanswered_rounds``:
    :attr:`Link.unanswered_rounds`."""
    connection = Connection(
        framing=framing, baud=baud, heartbeat_interval=heartbeat_interval,
        liveness_timeout=liveness_timeout, request_timeout=request_timeout,
        request_tries=request_tries, max_reference_delay=max_reference_delay,
        heartbeat_give_up=heartbeat_give_up, stale_periods=stale_periods,
        unanswered_rounds=unanswered_rounds,
    )

    async def reopen(factory: ProtocolFactory) -> tuple[asyncio.BaseTransport, asyncio.Protocol]:
        return await open_transport(url, baud, factory)

    link = Link(connection, name=name or url, url=url, reopen=reopen, reconnect=reconnect,
                reconnect_backoff=reconnect_backoff)
    link.set_read_latency(read_latency)
    return link
