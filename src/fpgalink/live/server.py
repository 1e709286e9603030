"""The live view's server: foxglove-sdk's WebSocket server (the ``foxglove.websocket.v1``
protocol Foxglove opens) with JSON channels, what it costs kept off the control path.

* A message is encoded only when a client is subscribed to its channel; with none, a
  publication costs one call that returns at once.
* The SDK sends from its own threads and never blocks the caller: what waits for a client is
  bounded by :data:`BACKLOG` messages per client, the oldest dropped first.
* A client that stops reading is let go once its bytes have stood unsent for
  :data:`~fpgalink.live.clients.STALL_S` seconds (:mod:`fpgalink.live.clients`), counted and
  said.
* A latched channel (the log channels) keeps its last messages for a client that subscribes
  later (:mod:`fpgalink.live.latch`): those are encoded even with no client, and each goes to
  each subscribed client by itself, through the SDK's per-sink ``log``.
"""

from __future__ import annotations

import asyncio
import functools
import json
import math
import threading
import time
from collections.abc import Callable
from typing import Any

from fpgalink.live.address import LiveAddress
from fpgalink.live.clients import StallJudge, connections, shut_down
from fpgalink.live.latch import Latch
from fpgalink.protocol.exitcodes import NotInstalled

__all__ = ["BACKLOG", "INSTALL_HINT", "LiveServer", "LiveStats", "require_sdk", "sink_id"]

#: Messages that may wait for one client (the SDK's ``message_backlog_size``): about half a
#: second of everything a two-board robot publishes.
BACKLOG = 2048
#: How often clients that stopped reading are looked for.
WATCH_S = 1.0
INSTALL_HINT = "--foxglove needs foxglove-sdk: pip install 'fpgalink[foxglove]'"
_ENCODE = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode


def _finite(value: Any) -> Any:
    """``value`` with every non-finite float as ``None`` (JSON's ``null``)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def require_sdk() -> None:
    """:class:`NotInstalled` (exit 8) unless foxglove-sdk imports."""
    try:
        import foxglove  # noqa: F401
    except ImportError:
        raise NotInstalled(INSTALL_HINT) from None


class LiveStats:
    """What the server did: counted, never silent."""

    def __init__(self) -> None:
        self.clients_seen = 0  #: subscriptions' distinct clients
        self.dropped_clients = 0  #: let go for not reading
        self.published = 0  #: messages handed to the SDK (a client subscribed)
        self.skipped = 0  #: publications with no client subscribed (not encoded, unless kept)
        self.replayed = 0  #: kept messages sent to a client that subscribed after them


def sink_id(client: Any) -> int:
    """The id foxglove-sdk sends to ``client`` by (``Channel.log(sink_id=…)``).

    Each WebSocket client is a sink of the server's context. The SDK's Rust and C++ APIs
    give a client's sink id; its Python binding (0.30) gives only the client id, so that is
    used where no ``sink_id`` is given: a client draws both as it connects, one after the
    other, from two process-wide counters that start at 1, and in a live view's process
    nothing else draws from either (no MCAP writer, no remote access through the SDK), so
    the two are equal. ``tests/fpgalink/live/test_latch.py`` holds the SDK to it: a message
    sent to one client by this id reaches it and no other. (Two clients whose connections
    open at the very same instant, on two of the SDK's threads, could draw them crosswise;
    a ``sink_id`` from the binding, as the Rust ``Client::sink_id``, ends that, and is used
    as soon as there is one.)"""
    sink = getattr(client, "sink_id", None)
    return int(client.id if sink is None else sink)


def _listener(clients: set[int], latches: dict[str, Latch], stats: LiveStats) -> Any:
    """foxglove-sdk's ServerListener (called from its threads): which clients subscribe, and
    each latched channel's subscribers. When a client leaves, the SDK tells of an
    unsubscription for each channel it held: a latch forgets the clients gone."""
    from foxglove.websocket import ServerListener

    counting = threading.Lock()  # the SDK's threads may call at once: no count lost

    class Listener(ServerListener):
        def on_subscribe(self, client: Any, channel: Any) -> None:
            clients.add(int(client.id))
            latch = latches.get(str(channel.topic))
            if latch is not None:
                replayed = latch.subscribe(sink_id(client))
                with counting:
                    stats.replayed += replayed

        def on_unsubscribe(self, client: Any, channel: Any) -> None:
            latch = latches.get(str(channel.topic))
            if latch is not None:
                latch.unsubscribe(sink_id(client))

    return Listener()


class LiveServer:
    """One WebSocket server and its JSON channels, by topic. ``start`` before use, ``stop``
    after; ``say`` reports what the server did (one line each: a client let go)."""

    def __init__(self, address: LiveAddress, name: str,
                 say: Callable[[str], None] = lambda text: None) -> None:
        self.address = address
        self.name = name
        self.say = say
        self.stats = LiveStats()
        self.port = 0
        self._context: Any = None
        self._server: Any = None
        self._channels: dict[str, Any] = {}
        self._latches: dict[str, Latch] = {}  #: the latched channels', by topic
        self._clients: set[int] = set()
        self._judge = StallJudge()
        self._watch: asyncio.Task[None] | None = None

    def start(self) -> None:
        """Listen (``OSError`` when the address is taken or not this machine's)."""
        require_sdk()
        import foxglove

        # Kept: the server holds its context weakly, and without it advertises nothing.
        self._context = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name=self.name, host=self.address.host, port=self.address.port,
                context=self._context,
                server_listener=_listener(self._clients, self._latches, self.stats),
                message_backlog_size=BACKLOG)
        except RuntimeError as exc:  # the SDK's error for a port in use, an unknown host
            raise OSError(str(exc)) from None
        self.port = int(self._server.port)
        try:
            self._watch = asyncio.get_running_loop().create_task(self._let_go_stalled())
        except RuntimeError:  # no loop: the backlog alone bounds a stalled client
            self._watch = None

    @property
    def url(self) -> str:
        return self.address.url(self.port)

    def channel(self, topic: str, schema: dict[str, Any],
                schema_name: str | None = None, *, latched: bool = False) -> None:
        """Advertise ``topic`` (JSON, with its JSON Schema; ``schema_name`` defaults to the
        schema's title: a Foxglove well-known name such as ``foxglove.PoseInFrame`` makes
        its panels understand it). ``latched``: it keeps its last messages for a client that
        subscribes later (:mod:`fpgalink.live.latch`) — for what is logged once and seldom
        (a fault), never for a stream."""
        import foxglove

        if topic in self._channels:
            return
        name = schema_name or str(schema.get("title", topic))
        if latched:
            # Before the channel: the SDK advertises it as it is made, and a client that
            # subscribes at once must find its latch.
            self._latches[topic] = Latch(functools.partial(self._send_to, topic))
        self._channels[topic] = foxglove.Channel(
            topic, schema=foxglove.Schema(name=name, encoding="jsonschema",
                                          data=json.dumps(schema).encode()),
            message_encoding="json", context=self._context)

    def _send_to(self, topic: str, data: bytes, log_time: int, sink: int) -> None:
        """A latched channel's message to one client (from a latch, under its lock)."""
        channel = self._channels.get(topic)
        if channel is not None:  # None once stopped (and while made, when nothing is kept)
            channel.log(data, log_time=log_time, sink_id=sink)

    def wanted(self, topic: str) -> bool:
        """Whether a client is subscribed to ``topic`` (nothing to encode otherwise), or
        ``topic`` keeps its messages for one that subscribes later."""
        if topic in self._latches:
            return True
        channel = self._channels.get(topic)
        return channel is not None and bool(channel.has_sinks())

    def publish(self, topic: str, record: dict[str, Any] | Callable[[], dict[str, Any]],
                log_time: float | None = None) -> None:
        """``record`` (or what it makes, only when wanted) on ``topic``, stamped
        ``log_time`` (host epoch s; default now)."""
        channel = self._channels.get(topic)
        if channel is None or (topic not in self._latches and not channel.has_sinks()):
            self.stats.skipped += 1
            return
        message = record() if callable(record) else record
        try:
            data = _ENCODE(message).encode()
        except ValueError:  # a non-finite number (a board can send one): JSON has none
            data = _ENCODE(_finite(message)).encode()
        self._log(topic, channel, data, time.time() if log_time is None else log_time)

    def publish_json(self, topic: str, data: bytes, log_time: float) -> None:
        """A message already encoded as JSON (the telemetry's fast path)."""
        channel = self._channels.get(topic)
        if channel is None:
            return
        self._log(topic, channel, data, log_time)

    def _log(self, topic: str, channel: Any, data: bytes, log_time: float) -> None:
        stamp = int(log_time * 1e9)
        latch = self._latches.get(topic)
        if latch is None:
            channel.log(data, log_time=stamp)
        elif not latch.publish(data, stamp):  # kept, and sent to each client subscribed
            self.stats.skipped += 1
            return
        self.stats.published += 1

    async def _let_go_stalled(self) -> None:
        while True:
            await asyncio.sleep(WATCH_S)
            self.stats.clients_seen = len(self._clients)
            seen = connections(self.port)
            if seen is None:
                return  # not Linux: nothing tells; the backlog bounds what waits
            for conn in self._judge.stalled(seen, time.monotonic()):
                if shut_down(conn.inode):
                    self.stats.dropped_clients += 1
                    self.say(f"live view: let go of the Foxglove client {conn.peer}: it "
                             f"stopped reading ({conn.unsent:,} bytes unsent for "
                             f"{self._judge.stall_s:g} s)")

    def stop(self) -> None:
        if self._watch is not None:
            self._watch.cancel()
        if self._server is not None:
            self._server.stop()
            self._server = None
        for channel in self._channels.values():
            channel.close()
        self._channels.clear()
        self._latches.clear()
