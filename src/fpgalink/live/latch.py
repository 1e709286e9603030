"""Log channels that keep their last messages for the clients that subscribe later.

A fault is logged once (``/robot/supervision``'s stop, ``/board/NAME/events``'
``board_restarted``), so a client that subscribes after it would never see it; yet the one
who opens Foxglove after a fault is the one who wants to know what happened. As ROS's
latched (``transient_local``) topics do for a late subscriber, a :class:`Latch` keeps a
channel's last :data:`KEPT` messages and gives them to each client that subscribes, before
anything newer: to that client only, so those already subscribed see each message once.

It decides, nothing more: what to send to which client; ``send`` (the server's) sends. It
is told of subscriptions from the server's threads and of messages from the event loop's:
one lock makes "sent to those subscribed, kept" and "sent what is kept, subscribed" atomic
with respect to each other, so a message is never both replayed to a client and sent to it
live, nor neither.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable

__all__ = ["KEPT", "Latch", "Send"]

#: The messages a log channel keeps: its last 50. Log channels carry what happens seldom
#: (a stop, a restart, a link lost and found), a handful in a run; 50 hold every one of a
#: fault's messages and of those that led to it, while a flood of events (a link flapping)
#: keeps memory at 50 messages of a few hundred bytes per channel, and a late client is
#: handed at most 50 at once, far under what may wait for it (server.BACKLOG).
KEPT = 50

#: ``send(data, log_time_ns, client)``: one message to one client.
Send = Callable[[bytes, int, int], None]


class Latch:
    """One channel's last ``kept`` messages and the clients subscribed to it, by the id the
    server sends to a client with."""

    def __init__(self, send: Send, kept: int = KEPT) -> None:
        self._send = send
        self._kept: deque[tuple[bytes, int]] = deque(maxlen=kept)  # the oldest go first
        self._clients: set[int] = set()
        self._lock = threading.Lock()

    def publish(self, data: bytes, log_time: int) -> int:
        """Keep a message and send it to each subscribed client; how many it went to."""
        with self._lock:
            self._kept.append((data, log_time))
            for client in self._clients:
                self._send(data, log_time, client)
            return len(self._clients)

    def subscribe(self, client: int) -> int:
        """``client`` subscribed: what is kept, to it alone; how many messages that was (none
        for a client already subscribed: it has had them)."""
        with self._lock:
            if client in self._clients:
                return 0
            for data, log_time in self._kept:
                self._send(data, log_time, client)
            self._clients.add(client)
            return len(self._kept)

    def unsubscribe(self, client: int) -> None:
        """``client`` unsubscribed or left: nothing more for it."""
        with self._lock:
            self._clients.discard(client)

    @property
    def kept(self) -> int:
        with self._lock:
            return len(self._kept)

    @property
    def clients(self) -> int:
        with self._lock:
            return len(self._clients)
