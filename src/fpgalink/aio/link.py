"""The asyncio link: a thin layer over the sans-I/O :class:`~fpgalink.Connection`.

Shaped like aioquic's protocol: a :class:`Link` is handed its connection and a transport.
It feeds received bytes to the connection, writes what the connection produces, arms one
loop timer at ``Connection.get_timer()``, and hands the connection's events on: request
outcomes to their futures (one per request; a cancelled one withdraws its request), the
rest to its subscribers (:mod:`.fanout`: telemetry, listeners, the status events). Every
protocol decision, every retry and every count lives in the connection; the link only
moves bytes, timers and futures. Read batching (:mod:`.batching`), the link's clock
(:mod:`.clock`) and the bound on what waits unwritten in its transport (:mod:`.backlog`:
a request refused with :class:`~fpgalink.errors.LineBusy` while the line is backed up)
are its helpers; so is :mod:`.identity` (``link.identification``: who the board is, asked
with ``open_link(…, identify=True)`` or ``await link.identification.identify()``, a board
of another protocol declaration refused, asked again after each restart).
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import Any, Unpack

from fpgalink.aio.backlog import MAX_LINE_BACKLOG_S, check_line
from fpgalink.aio.batching import ReadBatcher
from fpgalink.aio.clock import LinkClock, LinkTimer
from fpgalink.aio.fanout import Stamped, Subscribers
from fpgalink.aio.identity import Identification
from fpgalink.aio.subscription import Subscription
from fpgalink.aio.tasks import cancel_and_wait
from fpgalink.aio.transport import ProtocolFactory, open_transport
from fpgalink.connection import Connection, LinkOptions, LinkStats, Liveness
from fpgalink.errors import BoardLost, FpgalinkError, LinkClosed, PortError
from fpgalink.events import BoardRestarted, RequestDone, RequestFailed, StatusEvent
from fpgalink.protocol import (
    BoardIdentity,
    CountedMessage,
    DirectCommand,
    Event,
    Message,
    Param,
    References,
    Telemetry,
    resolve,
)
from fpgalink.protocol.params import iter_addresses

__all__ = [
    "MAX_LINE_BACKLOG_S",
    "Link",
    "LinkState",
    "Reopen",
    "Stamped",
    "Subscription",
    "SyncResult",
    "open_link",
]

#: Opens a transport to the board (again, after the port vanished), given the protocol.
Reopen = Callable[[ProtocolFactory], Awaitable[tuple[asyncio.BaseTransport, asyncio.Protocol]]]


class LinkState(Enum):
    CONNECTING = "connecting"
    CONNECTED = "connected"
    RECONNECTING = "reconnecting"  #: the port vanished; retrying with backoff
    CLOSED = "closed"


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


class _PortProtocol(asyncio.Protocol):
    """The link's end of one transport. A new one per (re)connection, so a late callback
    from a transport already replaced is recognised and ignored."""

    def __init__(self, on_data: Callable[[_PortProtocol, bytes], None],
                 on_lost: Callable[[_PortProtocol, Exception | None], None]) -> None:
        self._on_data = on_data
        self._on_lost = on_lost

    def data_received(self, data: bytes) -> None:
        self._on_data(self, data)

    def connection_lost(self, exc: Exception | None) -> None:
        self._on_lost(self, exc)


class Link:
    """One board. Use ``async with open_link(url) as link:`` so it always closes.

    ``Link(connection, transport)`` attaches to a transport already open (a test's
    :class:`~fpgalink.testing.MemoryTransport`, say). With ``reopen`` and no transport,
    :meth:`open` opens one, and with ``reconnect`` the link reopens it with backoff when the
    port vanishes; :func:`open_link` builds all of that from a URL. Who the board is:
    :attr:`identification` (asked at open with ``identify``; a mismatch refused unless
    ``allow_mismatch``)."""

    def __init__(self, connection: Connection, transport: asyncio.BaseTransport | None = None,
                 *, name: str = "board", url: str = "", reopen: Reopen | None = None,
                 reconnect: bool = True, reconnect_backoff: tuple[float, float] = (0.05, 2.0),
                 identify: bool = False, allow_mismatch: bool = False) -> None:
        self.connection = connection
        self.name = name
        self.url = url  #: where the board is, for messages
        self.reconnect = reconnect and reopen is not None
        self.reconnect_backoff = reconnect_backoff
        self.state = LinkState.CONNECTING
        self._reopen = reopen
        self._transport: asyncio.BaseTransport | None = None
        self._protocol: _PortProtocol | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._clock = LinkClock()
        self._timer = LinkTimer(self._clock, self._on_timer)
        self._futures: dict[int, asyncio.Future[int | float]] = {}
        self._subscribers: Subscribers[StatusEvent] = Subscribers(connection.stats)
        self._reconnect_task: asyncio.Task[None] | None = None
        self._port_released: asyncio.Event | None = None
        self.identification = Identification(  #: who the board is (docs/protocol.md §8)
            self, connection.identity, self._identified, where=url or name,
            at_open=identify, allow_mismatch=allow_mismatch)
        self._batches = ReadBatcher(lambda data: self._on_data(self._protocol, data),
                                    lambda: self._transport, lambda: bool(self._futures))
        if transport is not None:
            self._attach(transport)

    # --- lifecycle ------------------------------------------------------------------------

    def _protocol_factory(self) -> _PortProtocol:
        # Looked up at each call, not bound now: what the link does with a read is its own.
        self._protocol = _PortProtocol(lambda protocol, data: self._on_data(protocol, data),
                                       lambda protocol, exc: self._on_port_lost(protocol, exc))
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
        self._clock.follow(transport, self._timer.due)
        self.connection.boards_time = self._clock.far_end_time

    async def open(self) -> Link:
        """Connect (unless a transport was given) and start expecting the board."""
        self._loop = asyncio.get_running_loop()
        self._clock.start(self._loop)
        if self._transport is None:
            await self._connect()
        self.state = LinkState.CONNECTED
        self.connection.start(self._now())
        self._arm_timer()
        await self.identification.opened()
        return self

    async def close(self) -> None:
        """Send ``RD`` if enabled, fail pending requests with :class:`LinkClosed`, end every
        subscription and watcher, release the port. Safe to call twice."""
        if self.state is LinkState.CLOSED:
            self._end_waiters()
            return
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
            self._clock.start(self._loop)
        connected = self.state is LinkState.CONNECTED
        self.state = LinkState.CLOSED
        self.connection.close(self._now())
        if connected:
            self._write(self.connection.data_to_send())
        if self._reconnect_task is not None:
            await cancel_and_wait(self._reconnect_task)  # its failure: the link closes anyway
        await self.identification.close()
        self._timer.cancel()
        self._batches.cancel()
        self._process()
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
        self._subscribers.end()

    async def __aenter__(self) -> Link:
        return await self.open()

    async def __aexit__(self, *exc: object) -> None:
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
        waits for line room). A counted message other than ``RV`` raises
        :class:`~fpgalink.errors.LineBusy` while the line is backed up (see
        :data:`MAX_LINE_BACKLOG_S`)."""
        if isinstance(message, DirectCommand | References):
            self._ensure_connected()
        else:
            self._ensure_room(type(message).__name__)
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
        self._ensure_room(f"setting {param.full_name(code)}")
        return await self._request(self.connection.set_param(param, code, coerced, self._now()))

    async def get_param(self, name: str | int, channel: int | str | None = None) -> int | float:
        param, code = resolve(name, channel)
        self._ensure_room(f"reading {param.full_name(code)}")
        return await self._request(self.connection.get_param(param, code, self._now()))

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
        results: list[SyncResult] = []
        for param, code, coerced in _checked(values):
            label = param.full_name(code)
            try:
                self._ensure_room(f"setting {label}")
                confirmed = await self._request(
                    self.connection.set_param(param, code, coerced, self._now())
                )
                results.append(SyncResult(label, coerced, confirmed, None))
            except FpgalinkError as exc:
                results.append(SyncResult(label, coerced, None, exc))
        return results

    async def _request(self, request_id: int) -> int | float:
        """One future per request. Cancelled (the caller gave up: ``wait_for`` ran out, a
        task was cancelled), the request is withdrawn from the connection."""
        assert self._loop is not None
        future: asyncio.Future[int | float] = self._loop.create_future()
        self._futures[request_id] = future
        self._batches.resume()  # its answer must not wait for a batch
        self._flush()
        try:
            return await future
        except asyncio.CancelledError:
            if self.state is LinkState.CONNECTED:
                self.connection.cancel_request(request_id, self._now())
                self._flush()
            raise
        finally:
            self._futures.pop(request_id, None)

    # --- telemetry and events -------------------------------------------------------------

    def telemetry(self, maxsize: int = 1024) -> Subscription[Telemetry]:
        """A new independent subscriber. When its queue is full the oldest sample is dropped
        and counted (``sub.dropped``, ``link.stats.subscriber_drops``); the link never waits."""
        return self._subscribers.telemetry(maxsize)

    def stamped_telemetry(self, maxsize: int = 1024) -> Subscription[Stamped]:
        """As :meth:`telemetry`, each sample with the loop time the link received it — the
        host's side of the clock, beside the board's ``t_us``."""
        return self._subscribers.stamped(maxsize)

    def watch(self, maxsize: int = 256) -> AsyncIterator[StatusEvent]:
        """The status events (:class:`~fpgalink.events.StatusEvent`: the board lost, found,
        back, restarted, its faults, the port lost and restored …) as an async iterator; it
        ends after :class:`~fpgalink.events.Closed` when the link closes, for whatever
        reason."""
        return self._subscribers.watch(maxsize)

    def on_event(self, callback: Callable[[StatusEvent], None]) -> Callable[[], None]:
        """Call ``callback(event)`` for every status event, synchronously, as it happens: for
        reactions that must not wait for a task to be scheduled (a robot stopping its other
        boards when one goes silent). Keep it quick and do not raise. Returns a remover."""
        return self._subscribers.on_event(callback)

    def add_listener(self, listener: Callable[[Event], None]) -> Callable[[], None]:
        """Call ``listener(event)`` with everything the connection reports, in order: every
        received message (catalogued, generic, direct commands), ``Malformed``, framing
        errors, counter gaps, request outcomes… Returns a function that removes it.
        Listeners run inside the receive path: keep them quick and do not raise."""
        return self._subscribers.add_listener(listener)

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
        """The link's time (:class:`~fpgalink.aio.clock.LinkClock`)."""
        return self._clock.now()

    def _ensure_open(self) -> None:
        if self.state is LinkState.CLOSED:
            raise LinkClosed(f"{self.name}: link is closed")
        if self._loop is None:
            raise LinkClosed(f"{self.name}: link is not open yet (use `async with`)")

    def _ensure_connected(self) -> None:
        self._ensure_open()
        if self.state is not LinkState.CONNECTED or self._transport is None:
            raise BoardLost(f"{self.name}: port is disconnected ({self.state.value})")

    def _ensure_room(self, what: str) -> None:
        """Connected, and the line not backed up (else :class:`~fpgalink.errors.LineBusy`:
        :mod:`~fpgalink.aio.backlog`)."""
        self._ensure_connected()
        check_line(self._transport, self.connection.baud, self.connection.stats,
                   f"{self.name}: {what}")

    def _write(self, data: bytes) -> None:
        if data and self._transport is not None and self.state is not LinkState.RECONNECTING:
            self._transport.write(data)  # type: ignore[attr-defined]

    def _on_data(self, protocol: _PortProtocol | None, data: bytes) -> None:
        if protocol is not self._protocol or self.state is not LinkState.CONNECTED:
            return
        self.connection.receive_data(data, now := self._now())  # asked once: a far end's lag
        self._process(now)
        self._flush()
        self._batches.read()

    # --- read batching --------------------------------------------------------------------

    def set_read_latency(self, seconds: float | None) -> None:
        """Read in batches of up to ``seconds`` (None or 0: at once; :mod:`.batching`)."""
        self._batches.set_latency(seconds)

    @property
    def read_latency(self) -> float | None:
        return self._batches.latency

    def read_now(self) -> None:
        """Handle at once what the port holds: a batch under way ends now."""
        self._batches.resume()

    def _flush(self) -> None:
        self._write(self.connection.data_to_send())
        self._arm_timer()

    def _arm_timer(self) -> None:
        if self._loop is not None and self.state is not LinkState.CLOSED:
            self._timer.arm(self._loop, self.connection.get_timer())

    @property
    def timer_due(self) -> float | None:
        """When the link's timer fires next, on its clock (``None``: none): no later than
        ``connection.get_timer()``; sooner, it finds nothing due and is armed again."""
        return self._timer.due()

    def _on_timer(self) -> None:
        self._batches.read_now()  # what waits is the board's: read before any judgement
        self.connection.handle_timer(self._now())
        self._process()
        self._flush()

    def _process(self, now: float | None = None) -> None:
        """Hand out what the connection reported (at ``now``, default the link's time):
        every event to the listeners, telemetry to its subscriptions, status events to the
        watchers, request outcomes to their futures."""
        subscribers, futures = self._subscribers, self._futures
        now = self._now() if now is None else now
        for event in self.connection.events():
            subscribers.deliver(event, now)
            kind = type(event)
            if kind is RequestDone or kind is RequestFailed:
                future = futures.get(event.request_id)  # type: ignore[attr-defined]
                if future is not None and not future.done():
                    if isinstance(event, RequestDone):
                        future.set_result(event.value)
                    else:
                        assert isinstance(event, RequestFailed)
                        future.set_exception(event.error)
            elif isinstance(event, StatusEvent):
                subscribers.status(event)
                if kind is BoardRestarted:
                    self.identification.restarted()

    def _identified(self, identity: BoardIdentity | None) -> None:
        self.connection.identity.identified(identity, self._now())
        self._process()

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
        self.connection.port_lost(self._now(), reason, cause)
        if self.reconnect:
            self.state = LinkState.RECONNECTING
            self._process()
            self._reconnect_task = asyncio.ensure_future(self._reconnect_loop())
        else:
            self.state = LinkState.CLOSED
            self._timer.cancel()
            self.connection.close(self._now(), reason)
            self._process()
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
            self._process()
            self._flush()
            return


def _checked(values: Mapping[str, object] | Iterable[tuple[str, str | None, object]]
             ) -> list[tuple[Param, int, int | float]]:
    """``values`` (as :meth:`Link.sync_params` takes them) resolved and coerced: every one
    checked before the first byte is sent."""
    entries = ([(k, None, v) for k, v in values.items()] if isinstance(values, Mapping)
               else list(values))
    checked: list[tuple[Param, int, int | float]] = []
    for name, channel, value in entries:
        param, code = resolve(name, channel)
        checked.append((param, code, param.coerce(value)))
    return checked


def open_link(
    url: str = "emu://",
    baud: int = 1_000_000,
    *,
    name: str | None = None,
    reconnect: bool = True,
    reconnect_backoff: tuple[float, float] = (0.05, 2.0),
    read_latency: float | None = None,
    identify: bool = False,
    allow_mismatch: bool = False,
    **options: Unpack[LinkOptions],
) -> Link:
    """``async with open_link("/dev/ttyUSB0") as link:`` — a device path,
    ``socket://host:port``, or ``emu://`` for an emulated board in this process (any scheme
    a package registers). ``options`` are the connection's settings
    (:class:`~fpgalink.connection.Settings`: ``request_tries``, ``liveness_timeout``,
    ``unanswered_rounds`` …); ``reconnect`` reopens the URL with backoff when the port
    vanishes; ``read_latency`` lets the link batch reads (:meth:`Link.set_read_latency`);
    ``identify`` asks the board who it is as it opens (``link.identification``: one extra round
    trip, three for a seed board) and refuses one built from another protocol declaration
    unless ``allow_mismatch``."""
    connection = Connection(baud=baud, **options)

    async def reopen(factory: ProtocolFactory) -> tuple[asyncio.BaseTransport, asyncio.Protocol]:
        return await open_transport(url, baud, factory)

    link = Link(connection, name=name or url, url=url, reopen=reopen, reconnect=reconnect,
                reconnect_backoff=reconnect_backoff, identify=identify,
                allow_mismatch=allow_mismatch)
    link.set_read_latency(read_latency)
    return link
