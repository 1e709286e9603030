"""A client of Foxglove's WebSocket protocol (``foxglove.websocket.v1``; foxglove-sdk
serves it under the subprotocol name ``foxglove.sdk.v1``), as Foxglove speaks it: the
server's info, its channel advertisements, a subscription to each, and every message decoded
(JSON channels), with the ``websockets`` library."""

from __future__ import annotations

import asyncio
import json
import struct
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

import websockets
from websockets.typing import Subprotocol

#: The protocol's names for its subprotocol; a server picks the one it speaks.
SUBPROTOCOLS = [Subprotocol("foxglove.sdk.v1"), Subprotocol("foxglove.websocket.v1")]
OP_MESSAGE_DATA = 0x01


@dataclass
class Received:
    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)  #: id → advertisement
    messages: dict[str, list[tuple[int, Any]]] = field(default_factory=lambda: defaultdict(list))
    statuses: list[dict[str, Any]] = field(default_factory=list)
    closed: bool = False  #: the server closed the connection before the time was up

    def topics(self) -> set[str]:
        return {c["topic"] for c in self.channels.values()}

    def latest(self, topic: str) -> Any:
        return self.messages[topic][-1][1]


async def watch(url: str, seconds: float, wanted: set[str] | None = None) -> Received:
    """Connect, subscribe to every channel advertised (or those in ``wanted``) and decode
    what comes for ``seconds``."""
    got = Received()
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        loop = asyncio.get_running_loop()
        end = loop.time() + seconds
        by_subscription: dict[int, str] = {}
        while (left := end - loop.time()) > 0:
            try:
                frame = await asyncio.wait_for(ws.recv(), left)
            except TimeoutError:
                break
            except websockets.ConnectionClosed:  # the server's program ended: what came
                got.closed = True
                break
            if isinstance(frame, bytes):
                if frame[0] == OP_MESSAGE_DATA:
                    subscription, log_time = struct.unpack_from("<IQ", frame, 1)
                    topic = by_subscription[subscription]
                    got.messages[topic].append((log_time, json.loads(frame[13:])))
                continue
            message = json.loads(frame)
            if message["op"] == "serverInfo":
                got.server_info = message
            elif message["op"] == "advertise":
                new = []
                for channel in message["channels"]:
                    got.channels[channel["id"]] = channel
                    if wanted is None or channel["topic"] in wanted:
                        new.append(channel)
                subscriptions = [{"id": c["id"], "channelId": c["id"]} for c in new]
                for c in new:
                    by_subscription[c["id"]] = c["topic"]
                if subscriptions:
                    await ws.send(json.dumps({"op": "subscribe",
                                              "subscriptions": subscriptions}))
            elif message["op"] == "status":
                got.statuses.append(message)
    return got
