"""The asyncio link: a thin layer over the sans-I/O :class:`~fpgalink.Connection`.

It owns a transport (serial, TCP or an in-process emulator), feeds received bytes to the
connection, writes what the connection produces, arms one loop timer at
``Connection.get_timer()``, and turns events into futures (one per pending request),
telemetry subscriptions and link events. All protocol decisions live in the core.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections import deque
from collections.abc import AsyncIterator, Callable, Iterable, Mapping
from dataclasses import dataclass
from enum import Enum
from types import TracebackType
from typing import Any

from fpgalink._framing import DEFAULT_FRAMING, Framing
from fpgalink._messages import CountedMessage, DirectCommand
from fpgalink._state import EnableState, Liveness
from fpgalink.aio.transport import connect
from fpgalink.catalogue import Message, References, Telemetry
from fpgalink.connection import (
    BoardFound,
    BoardSilent,
    Connection,
    LinkStats,
    RequestDone,
    RequestFailed,
)
from fpgalink.errors import BoardLost, FpgalinkError, LinkClosed, PortError
from fpgalink.params import Param, resolve

__all__ = [
    "Link",
    "LinkEvent",
    "LinkEventKind",
    "LinkState",
    "SyncResult",
    "TelemetrySubscription",
    "open_link",
]


class LinkState(Enum):
    CONNECTING = "connecting"
    CONNECTED = "connected"
    RECONNECTING = "reconnecting"  #: the port vanished; retrying with backoff
    CLOSED = "closed"


class LinkEventKind(Enum):
    BOARD_LOST = "board_lost"  #: no well-formed message for ``liveness_timeout``
    BOARD_FOUND = "board_found"
    PORT_LOST = "port_lost"  #: the device or socket went away
    PORT_RESTORED = "port_restored"


@dataclass(frozen=True, slots=True)
class LinkEvent:
    kind: LinkEventKind
    at: float  #: loop time
    detail: str = ""


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


class _Subscription:
    """A bounded queue that drops its oldest item when full and counts the drop."""

    def __init__(self, maxsize: int) -> None:
        if maxsize < 1:
            raise ValueError("maxsize must be at least 1")
        self._items: deque[Any] = deque(maxlen=maxsize)
        self._ready = asyncio.Event()
        self._closed = False
        self.dropped = 0

    def _push(self, item: Any) -> bool:
        dropped = len(self._items) == self._items.maxlen
        if dropped:
            self.dropped += 1
        self._items.append(item)
        self._ready.set()
        return dropped

    def _close(self) -> None:
        self._closed = True
        self._ready.set()

    async def get(self) -> Any:
        while not self._items:
            if self._closed:
                raise StopAsyncIteration
            self._ready.clear()
            await self._ready.wait()
        return self._items.popleft()

    def __len__(self) -> int:
        return len(self._items)


class TelemetrySubscription(_Subscription):
    """``async for sample in link.telemetry(): ...`` — ends when the link closes."""

    def __init__(self, link: Link, maxsize: int) -> None:
        super().__init__(maxsize)
        self._link = link

    def __aiter__(self) -> TelemetrySubscription:
        return self

    async def __anext__(self) -> Telemetry:
        sample: Telemetry = await self.get()
        return sample

    def close(self) -> None:
        self._link._telemetry_subs.discard(self)
        self._close()

    async def __aenter__(self) -> TelemetrySubscription:
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()


class _EventSubscription(_Subscription):
    def __aiter__(self) -> _EventSubscription:
        return self

    async def __anext__(self) -> LinkEvent:
        event: LinkEvent = await self.get()
        return event


class _LinkProtocol(asyncio.Protocol):
    def __init__(self, link: Link) -> None:
        self._link = link

    def data_received(self, data: bytes) -> None:
        self._link._on_data(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self._link._on_port_lost(exc)


class Link:
    """One board. Use ``async with open_link(url) as link:`` so it always closes."""

    def __init__(
        self,
        url: str,
        *,
        baud: int = 1_000_000,
        framing: Framing = DEFAULT_FRAMING,
        heartbeat_interval: float = 0.1,
        liveness_timeout: float = 0.7,
        request_timeout: float = 0.05,
        request_tries: int = 8,
        reconnect: bool = True,
        reconnect_backoff: tuple[float, float] = (0.05, 2.0),
        name: str | None = None,
    ) -> None:
        self.url = url
        self.baud = baud
        self.name = name or url
        self.reconnect = reconnect
        self.reconnect_backoff = reconnect_backoff
        self._conn = Connection(
            framing=framing,
            heartbeat_interval=heartbeat_interval,
            liveness_timeout=liveness_timeout,
            request_timeout=request_timeout,
            request_tries=request_tries,
        )
        self.state = LinkState.CONNECTING
        self._transport: asyncio.BaseTransport | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._timer_at: float | None = None
        self._futures: dict[int, asyncio.Future[int | float]] = {}
        self._telemetry_subs: set[TelemetrySubscription] = set()
        self._event_subs: set[_EventSubscription] = set()
        self._listeners: list[Callable[[Any], None]] = []
        self._reconnect_task: asyncio.Task[None] | None = None
        self._port_released = asyncio.Event()
        self.reconnects = 0
        self.port_losses = 0

    # --- lifecycle ------------------------------------------------------------------------

    async def open(self) -> Link:
        self._loop = asyncio.get_running_loop()
        await self._connect()
        self._conn.start_liveness(self._loop.time())
        self._arm_timer()
        return self

    async def _connect(self) -> None:
        transport, _ = await connect(self.url, self.baud, lambda: _LinkProtocol(self))
        self._transport = transport
        self.state = LinkState.CONNECTED

    async def close(self) -> None:
        """Stop the heartbeat (sending ``RD`` if enabled), fail pending requests with
        :class:`LinkClosed`, end subscriptions, release the port. Safe to call twice."""
        if self.state is LinkState.CLOSED:
            return
        if self._conn.enable_state is EnableState.ENABLED and self.state is LinkState.CONNECTED:
            with contextlib.suppress(Exception):
                self._conn.disable(self._now())
                self._flush()
        self.state = LinkState.CLOSED
        if self._reconnect_task is not None:
            self._reconnect_task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._reconnect_task
        if self._timer is not None:
            self._timer.cancel()
        self._conn.close()
        self._process()
        for future in self._futures.values():
            if not future.done():
                future.set_exception(LinkClosed(f"{self.name}: link closed"))
        self._futures.clear()
        for sub in list(self._telemetry_subs):
            sub.close()
        for esub in list(self._event_subs):
            esub._close()
        transport, self._transport = self._transport, None
        if transport is not None:
            # Wait until the transport says it is gone (it may first flush the RD just
            # written): only then is the port released and can be opened again.
            self._port_released.clear()
            transport.close()
            try:
                await asyncio.wait_for(self._port_released.wait(), 1.0)
            except TimeoutError:
                abort = getattr(transport, "abort", None)
                if abort is not None:
                    abort()
                await asyncio.sleep(0)

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

    async def enable(self) -> None:
        """Send ``RE`` now and every heartbeat interval until :meth:`disable` or close."""
        self._ensure_open()
        self._conn.enable(self._now())
        self._flush()

    async def disable(self) -> None:
        """Stop the heartbeat and send ``RD``: the board disables at once."""
        self._ensure_open()
        self._conn.disable(self._now())
        self._flush()

    @property
    def enabled(self) -> bool:
        return self._conn.enable_state is EnableState.ENABLED

    async def set_references(self, ref_a: float, ref_b: float) -> None:
        """Send ``RV`` (deg/s in speed control)."""
        for value in (ref_a, ref_b):
            if not math.isfinite(value):
                raise ValueError(f"references must be finite numbers, got {value!r}")
        self.send(References(float(ref_a), float(ref_b)))

    def send(self, message: Message | CountedMessage | DirectCommand) -> bytes:
        """Send any message; returns the exact wire bytes written."""
        self._ensure_connected()
        wire = self._conn.send(message)
        assert self._transport is not None
        self._transport.write(wire)  # type: ignore[attr-defined]
        return wire

    async def set_param(
        self, name: str | int, value: int | float, channel: int | str | None = None
    ) -> int | float:
        """Set a parameter and return the value the board confirms is in force.

        Raises :class:`~fpgalink.errors.ParameterError` before sending for a bad name,
        channel, type or range; :class:`~fpgalink.errors.ParameterRefused` on ``PN``;
        :class:`~fpgalink.errors.RequestTimeout` when every try went unanswered."""
        param, code = resolve(name, channel)
        coerced = param.coerce(value)
        self._ensure_connected()
        return await self._request(self._conn.set_param(param, code, coerced, self._now()))

    async def get_param(self, name: str | int, channel: int | str | None = None) -> int | float:
        param, code = resolve(name, channel)
        self._ensure_connected()
        return await self._request(self._conn.get_param(param, code, self._now()))

    async def sync_params(
        self, values: Mapping[str, int | float] | Iterable[tuple[str, str | None, int | float]]
    ) -> list[SyncResult]:
        """Set many parameters, one at a time (the board's RX RAM holds two frames), and
        report each: keys are ``"Kp_Wheel_PidA"`` style names, or give
        ``(name, channel, value)`` triples. Host-side validation happens for all of them
        before the first byte is sent."""
        items: list[tuple[Param, int, int | float, int | float]] = []
        entries = (
            [(k, None, v) for k, v in values.items()] if isinstance(values, Mapping)
            else list(values)
        )
        for name, channel, value in entries:
            param, code = resolve(name, channel)
            items.append((param, code, value, param.coerce(value)))
        results: list[SyncResult] = []
        for param, code, requested, coerced in items:
            label = param.full_name(code)
            try:
                self._ensure_connected()
                confirmed = await self._request(
                    self._conn.set_param(param, code, coerced, self._now())
                )
                results.append(SyncResult(label, requested, confirmed, None))
            except FpgalinkError as exc:
                results.append(SyncResult(label, requested, None, exc))
        return results

    async def _request(self, request_id: int) -> int | float:
        assert self._loop is not None
        future: asyncio.Future[int | float] = self._loop.create_future()
        self._futures[request_id] = future
        self._flush()
        try:
            return await future
        finally:
            self._futures.pop(request_id, None)

    # --- telemetry and events -------------------------------------------------------------

    def telemetry(self, maxsize: int = 1024) -> TelemetrySubscription:
        """A new independent subscriber. When its queue is full the oldest sample is dropped
        and counted (``sub.dropped``, ``link.stats.subscriber_drops``); the link never waits."""
        sub = TelemetrySubscription(self, maxsize)
        if self.state is LinkState.CLOSED:
            sub._close()
        else:
            self._telemetry_subs.add(sub)
        return sub

    def watch(self, maxsize: int = 256) -> AsyncIterator[LinkEvent]:
        """Link events (board lost/found, port lost/restored) as an async iterator."""
        sub = _EventSubscription(maxsize)
        if self.state is LinkState.CLOSED:
            sub._close()
        else:
            self._event_subs.add(sub)
        return sub

    def add_listener(self, listener: Callable[[Any], None]) -> Callable[[], None]:
        """Call ``listener(event)`` with everything the protocol core reports, in order:
        every received message (catalogued, generic, direct commands), ``Malformed``, framing
        errors, counter gaps… Returns a function that removes the listener. Listeners run
        inside the receive path: keep them quick and do not raise."""
        self._listeners.append(listener)

        def remove() -> None:
            if listener in self._listeners:
                self._listeners.remove(listener)

        return remove

    @property
    def latest(self) -> Telemetry | None:
        """The newest telemetry sample, or ``None`` before the first."""
        return self._conn.latest_telemetry

    @property
    def stats(self) -> LinkStats:
        return self._conn.stats

    @property
    def board_alive(self) -> bool:
        return self._conn.liveness is Liveness.ALIVE

    @property
    def connection(self) -> Connection:
        """The sans-I/O core, for inspection."""
        return self._conn

    # --- plumbing -------------------------------------------------------------------------

    def _now(self) -> float:
        assert self._loop is not None
        return self._loop.time()

    def _ensure_open(self) -> None:
        if self.state is LinkState.CLOSED:
            raise LinkClosed(f"{self.name}: link is closed")

    def _ensure_connected(self) -> None:
        self._ensure_open()
        if self.state is not LinkState.CONNECTED or self._transport is None:
            raise BoardLost(f"{self.name}: port is disconnected ({self.state.value})")

    def _on_data(self, data: bytes) -> None:
        self._conn.receive_data(data, self._now())
        self._process()
        self._flush()

    def _flush(self) -> None:
        data = self._conn.data_to_send()
        if data and self._transport is not None and self.state is LinkState.CONNECTED:
            self._transport.write(data)  # type: ignore[attr-defined]
        self._arm_timer()

    def _arm_timer(self) -> None:
        if self._loop is None or self.state is LinkState.CLOSED:
            return
        deadline = self._conn.get_timer()
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
        self._timer = self._loop.call_at(deadline, self._on_timer)

    def _on_timer(self) -> None:
        self._timer = None
        self._timer_at = None
        self._conn.handle_timer(self._now())
        self._process()
        self._flush()

    def _emit(self, kind: LinkEventKind, detail: str = "") -> None:
        event = LinkEvent(kind, self._now(), detail)
        for sub in self._event_subs:
            sub._push(event)

    def _process(self) -> None:
        stats = self._conn.stats
        listeners = self._listeners
        for event in self._conn.events():
            for listener in listeners:
                listener(event)
            kind = type(event)
            if kind is Telemetry:
                for sub in self._telemetry_subs:
                    if sub._push(event):
                        stats.subscriber_drops += 1
            elif kind is RequestDone:
                future = self._futures.get(event.request_id)
                if future is not None and not future.done():
                    future.set_result(event.value)
            elif kind is RequestFailed:
                future = self._futures.get(event.request_id)
                if future is not None and not future.done():
                    future.set_exception(event.error)
            elif kind is BoardSilent:
                self._emit(LinkEventKind.BOARD_LOST, f"silent for {event.silent_for:.3f} s")
            elif kind is BoardFound:
                self._emit(LinkEventKind.BOARD_FOUND)

    def _on_port_lost(self, exc: Exception | None) -> None:
        if self.state is LinkState.CLOSED:
            self._port_released.set()
            return
        self._transport = None
        self.port_losses += 1
        stats = self._conn.stats
        stats.port_losses += 1
        reason = f"{self.name}: port lost ({exc or 'closed by the other end'})"
        self._conn.fail_requests(BoardLost(reason))
        self._process()
        self._emit(LinkEventKind.PORT_LOST, reason)
        if self.reconnect:
            self.state = LinkState.RECONNECTING
            self._reconnect_task = asyncio.ensure_future(self._reconnect_loop())
        else:
            self.state = LinkState.CLOSED
            for sub in list(self._telemetry_subs):
                sub.close()

    async def _reconnect_loop(self) -> None:
        delay, ceiling = self.reconnect_backoff
        while self.state is LinkState.RECONNECTING:
            await asyncio.sleep(delay)
            delay = min(delay * 2, ceiling)
            try:
                await self._connect()
            except PortError:
                continue
            self.reconnects += 1
            self._conn.stats.reconnects += 1
            # The board may have restarted: its counter need not continue ours.
            self._conn.counter_tracker.reset()
            self._conn.reset_receiver()
            if self._conn.enable_state is EnableState.ENABLED:
                self._conn.enable(self._now())
            self._flush()
            self._emit(LinkEventKind.PORT_RESTORED)
            return


def open_link(url: str = "emu://", baud: int = 1_000_000, **options: Any) -> Link:
    """``async with open_link("/dev/ttyUSB0") as link:`` — a device path,
    ``socket://host:port``, or ``emu://`` for an emulated board in this process. Options are
    :class:`Link`'s keyword arguments (timeouts, tries, heartbeat, reconnect, name)."""
    return Link(url, baud=baud, **options)
