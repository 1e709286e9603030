"""The log channels keep their last messages for a client that subscribes later
(src/fpgalink/live/latch.py): the latch alone, then the live view's server with clients
speaking Foxglove's protocol, in this process. Nothing sleeps and hopes: each wait is for a
message or a count, with a time limit, and a last message on a channel marks the end of
what a client was sent on it (the SDK sends a client's messages in order)."""

from __future__ import annotations

import asyncio
import json
import struct
import threading
import time
from collections import defaultdict
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

import pytest

from fpgalink.live.address import parse_address
from fpgalink.live.latch import KEPT, Latch
from fpgalink.live.server import BACKLOG, LiveServer
from fpgalink.recording import EVENT_SCHEMA, log_record

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets")

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
OP_MESSAGE_DATA = 0x01
LOG = "/robot/supervision"
EVENTS = "/board/L/events"
WAIT_S = 10.0


# The latch alone: what goes to which client.

def _recorder() -> tuple[list[tuple[bytes, int, int]], Callable[[bytes, int, int], None]]:
    sent: list[tuple[bytes, int, int]] = []
    return sent, lambda data, log_time, client: sent.append((data, log_time, client))


def test_a_late_client_is_sent_what_is_kept_and_no_other_client_again() -> None:
    sent, send = _recorder()
    latch = Latch(send)
    latch.subscribe(1)
    assert latch.publish(b"stop", 10) == 1
    assert latch.publish(b"restart", 11) == 1
    assert sent == [(b"stop", 10, 1), (b"restart", 11, 1)]
    sent.clear()
    assert latch.subscribe(2) == 2  # the late one: what is kept, to it alone, in order
    assert sent == [(b"stop", 10, 2), (b"restart", 11, 2)]
    sent.clear()
    assert latch.subscribe(2) == 0  # already subscribed: it has had them
    assert latch.publish(b"ready", 12) == 2
    assert sorted(sent) == [(b"ready", 12, 1), (b"ready", 12, 2)]
    sent.clear()
    latch.unsubscribe(1)
    latch.unsubscribe(1)  # twice, as a client that unsubscribes and then leaves
    latch.publish(b"enabled", 13)
    assert sent == [(b"enabled", 13, 2)]
    assert latch.clients == 1


def test_a_flood_keeps_only_the_last_messages() -> None:
    sent, send = _recorder()
    latch = Latch(send)
    for i in range(100_000):
        latch.publish(b"%d" % i, i)
    assert latch.kept == KEPT == 50
    assert latch.subscribe(7) == KEPT
    assert [log_time for _, log_time, _ in sent] == list(range(100_000 - KEPT, 100_000))


def test_a_client_subscribing_while_messages_come_gets_each_once_in_order() -> None:
    """Subscriptions come from the SDK's threads, messages from the event loop's: whenever
    a client subscribes, it gets the kept messages then the live ones, with no gap and none
    twice."""
    got: dict[int, list[int]] = defaultdict(list)
    latch = Latch(lambda data, log_time, client: got[client].append(log_time))
    total = 20_000
    started = threading.Event()

    def publisher() -> None:
        for i in range(total):
            if i == 1000:
                started.set()
            latch.publish(b"", i)

    thread = threading.Thread(target=publisher)
    thread.start()
    assert started.wait(WAIT_S)
    for client in range(1, 9):
        latch.subscribe(client)
    thread.join(WAIT_S)
    assert not thread.is_alive()
    for client in range(1, 9):
        seen = got[client]
        assert seen == list(range(seen[0], total)), client  # consecutive, to the last
        assert len(seen) >= KEPT


# The server: clients speaking Foxglove's protocol.


class _Client:
    """A Foxglove client that subscribes when told and keeps each message by topic."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.channels: dict[str, int] = {}  #: topic → channel id, as advertised
        self.messages: dict[str, list[dict[str, Any]]] = defaultdict(list)
        self._topics: dict[int, str] = {}  #: subscription id → topic
        self._news = asyncio.Event()
        self._reader = asyncio.create_task(self._read())

    async def _read(self) -> None:
        async for frame in self.ws:
            if isinstance(frame, bytes):
                if frame[0] == OP_MESSAGE_DATA:
                    subscription = struct.unpack_from("<I", frame, 1)[0]
                    self.messages[self._topics[subscription]].append(json.loads(frame[13:]))
            else:
                message = json.loads(frame)
                if message["op"] == "advertise":
                    self.channels.update({c["topic"]: c["id"] for c in message["channels"]})
            self._news.set()

    async def _until(self, ready: Callable[[], bool], what: str) -> None:
        try:
            async with asyncio.timeout(WAIT_S):
                while not ready():
                    self._news.clear()
                    if self._reader.done():
                        self._reader.result()
                        raise AssertionError(f"the server closed before {what}")
                    await self._news.wait()
        except TimeoutError:
            raise AssertionError(f"no {what} in {WAIT_S:g} s; got {dict(self.messages)}") from None

    async def subscribe(self, *topics: str) -> None:
        await self._until(lambda: all(t in self.channels for t in topics), "its channels")
        subscriptions = []
        for topic in topics:
            ident = self.channels[topic]
            self._topics[ident] = topic
            subscriptions.append({"id": ident, "channelId": ident})
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    async def received(self, topic: str, last: str) -> list[str]:
        """The messages on ``topic`` up to the one whose text is ``last``."""
        def arrived() -> bool:
            return any(m["message"] == last for m in self.messages[topic])
        await self._until(arrived, f"{last!r} on {topic}")
        return [m["message"] for m in self.messages[topic]]


@asynccontextmanager
async def _client(url: str) -> AsyncIterator[_Client]:
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        client = _Client(ws)
        try:
            yield client
        finally:
            client._reader.cancel()


@asynccontextmanager
async def _server() -> AsyncIterator[LiveServer]:
    server = LiveServer(parse_address("0"), "latch test")
    server.start()
    server.channel(LOG, EVENT_SCHEMA, latched=True)
    server.channel(EVENTS, EVENT_SCHEMA, latched=True)
    server.channel("/board/L/stats", {"title": "stats", "type": "object"})
    try:
        yield server
    finally:
        server.stop()


def _log(server: LiveServer, topic: str, text: str) -> None:
    now = time.time()
    server.publish(topic, log_record(text, "", now, "robot", 4), now)


async def _until(ready: Callable[[], bool], what: str) -> None:
    """``ready()`` within the time limit (for what the server's threads do, which no message
    to a client tells)."""
    deadline = time.monotonic() + WAIT_S
    while not ready():
        assert time.monotonic() < deadline, f"not {what} in {WAIT_S:g} s"
        await asyncio.sleep(0.01)


async def test_a_client_that_subscribes_after_a_fault_is_sent_it_and_no_other_twice() -> None:
    async with _server() as server, _client(server.url) as late, _client(server.url) as early:
        # The late client connected first: what it is sent goes by its own sink id
        # (server.sink_id, which this holds the SDK to), not to whoever came last.
        latches = (server._latches[LOG], server._latches[EVENTS])
        await early.subscribe(LOG, EVENTS)
        # Both: the SDK takes one message's subscriptions one after the other.
        await _until(lambda: all(latch.clients == 1 for latch in latches),
                     "the early client subscribed to both")
        _log(server, LOG, "enabled")
        _log(server, EVENTS, "board_restarted: board L restarted")
        _log(server, LOG, "stopped: board L restarted")
        assert await early.received(LOG, "stopped: board L restarted") == [
            "enabled", "stopped: board L restarted"]

        await late.subscribe(LOG, EVENTS)  # after the fault
        assert await late.received(LOG, "stopped: board L restarted") == [
            "enabled", "stopped: board L restarted"]
        assert await late.received(EVENTS, "board_restarted: board L restarted") == [
            "board_restarted: board L restarted"]

        # Then the live ones, to both; the early client had nothing twice.
        _log(server, LOG, "ready")
        _log(server, EVENTS, "end")
        for client in (early, late):
            assert await client.received(LOG, "ready") == [
                "enabled", "stopped: board L restarted", "ready"]
            assert await client.received(EVENTS, "end") == [
                "board_restarted: board L restarted", "end"]
        assert server.stats.replayed == 3


async def test_a_flood_of_events_reaches_a_late_client_as_its_last_fifty() -> None:
    async with _server() as server:
        for i in range(10 * BACKLOG):
            _log(server, EVENTS, f"lost {i}")
        assert server._latches[EVENTS].kept == KEPT
        async with _client(server.url) as client:
            await client.subscribe(EVENTS)
            last = f"lost {10 * BACKLOG - 1}"
            assert await client.received(EVENTS, last) == [
                f"lost {i}" for i in range(10 * BACKLOG - KEPT, 10 * BACKLOG)]
            _log(server, EVENTS, "end")
            assert (await client.received(EVENTS, "end"))[-2:] == [last, "end"]


async def test_a_client_that_leaves_is_forgotten() -> None:
    async with _server() as server:
        latch = server._latches[LOG]
        for _ in range(3):
            async with _client(server.url) as client:
                await client.subscribe(LOG, "/board/L/stats")
                await _until(lambda: latch.clients == 1, "subscribed")
            await _until(lambda: latch.clients == 0, "forgotten once it left")
        _log(server, LOG, "nobody")  # kept, sent to no one
        assert latch.kept == 1 and server.stats.skipped == 1


async def test_a_stream_is_not_latched() -> None:
    async with _server() as server:
        server.publish("/board/L/stats", {"lost": 1})  # nobody subscribed: gone
        async with _client(server.url) as client:
            await client.subscribe("/board/L/stats", LOG)
            await _until(lambda: server._latches[LOG].clients == 1, "subscribed")
            await _until(lambda: server.wanted("/board/L/stats"), "the SDK has it")
            server.publish("/board/L/stats", {"lost": 2})
            _log(server, LOG, "end")
            await client.received(LOG, "end")
            await _until(lambda: bool(client.messages["/board/L/stats"]), "stats")
            assert client.messages["/board/L/stats"] == [{"lost": 2}]
