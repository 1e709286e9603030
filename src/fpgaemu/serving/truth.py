"""The emulated robot's truth on a TCP port (``fpgaemu serve --robot --truth``): the body's
true state and each board as the emulator sees it, one JSON line every 20 ms to every
reader."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import time

from fpgaemu.serving.listening import ListeningEndpoint, turn_away
from fpgaemu.serving.pacing import PacedRobot

__all__ = ["MAX_TRUTH_READERS", "TRUTH_BACKLOG_BYTES", "TRUTH_PERIOD_S", "TRUTH_SNDBUF_BYTES",
           "TruthEndpoint", "error_line"]

#: How often the truth endpoint sends the body's state (50 Hz: a path plot's resolution).
TRUTH_PERIOD_S = 0.02
#: The most truth readers served at once; the next is sent one ``{"error": "busy: …"}`` line
#: and disconnected.
MAX_TRUTH_READERS = 32
#: Truth a reader may leave unread in serve's buffer (about 3 s of lines) before it is let
#: go: its connection is aborted, not drained, so nothing of it stays.
TRUTH_BACKLOG_BYTES = 128 * 1024
#: The kernel's send buffer for a truth reader (doubled by Linux), so a reader that stops
#: reading is noticed in seconds, not minutes.
TRUTH_SNDBUF_BYTES = 64 * 1024


class _TruthReader(asyncio.Protocol):
    """One reader of the truth stream. What it sends is not even read."""

    def __init__(self, endpoint: TruthEndpoint, connection: socket.socket) -> None:
        self.endpoint = endpoint
        self.connection = connection  #: the accepted socket, while it is being attached
        self.transport: asyncio.WriteTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        transport.pause_reading()
        self.endpoint.reader_joined(self)

    def connection_lost(self, exc: Exception | None) -> None:
        self.endpoint.reader_left(self)


class TruthEndpoint(ListeningEndpoint):
    """The emulated body's true state for up to :data:`MAX_TRUTH_READERS` readers on a TCP
    port: one JSON object per line every :data:`TRUTH_PERIOD_S` (``t x y theta v omega
    distance surface``; metres, radians, seconds of emulated time; ``boards``: each board's
    state, see :func:`~fpgaemu.serving.record.board_record`; ``host_time``: the host's epoch
    time the boards were advanced to, so board time maps onto the host clock). Read-only.
    Each line is built once and the same bytes are written to every reader, so the boards'
    timing does not depend on how many watch; a reader more than
    :data:`TRUTH_BACKLOG_BYTES` behind is aborted."""

    def __init__(self, robot: PacedRobot, host: str, port: int) -> None:
        super().__init__(host, port, error_line("busy: serve has no file descriptor left"),
                         backlog=64)
        self.robot = robot
        self._readers: set[_TruthReader] = set()
        self._attaching: set[socket.socket] = set()  #: accepted, not yet readers
        self._timer: asyncio.Handle | None = None
        self.publications = 0  #: lines built (each sent to every reader)
        self.turned_away = 0  #: readers refused over the cap
        self.aborted = 0  #: readers let go for not reading

    @property
    def readers(self) -> int:
        return len(self._readers)

    async def start(self) -> None:
        self.listener.open()

    def accepted(self, connection: socket.socket) -> None:
        if len(self._readers) + len(self._attaching) >= MAX_TRUTH_READERS:
            self.turned_away += 1
            turn_away(connection, error_line(
                f"busy: {MAX_TRUTH_READERS} truth readers are connected, the most serve "
                "takes"))
            return
        with contextlib.suppress(OSError):
            connection.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, TRUTH_SNDBUF_BYTES)
        self._attaching.add(connection)
        self.spawn(self._attach(connection))

    async def _attach(self, connection: socket.socket) -> None:
        try:
            await self.attach(connection, lambda: _TruthReader(self, connection))
        finally:
            self._attaching.discard(connection)

    def reader_joined(self, reader: _TruthReader) -> None:
        """A reader's connection is made (its protocol says so)."""
        # A reader from now on, counted once: no longer among those being attached.
        self._attaching.discard(reader.connection)
        self._readers.add(reader)
        if self._timer is None:  # the first reader: publish now, then every period
            self._timer = asyncio.get_running_loop().call_soon(self._publish)

    def reader_left(self, reader: _TruthReader) -> None:
        self._readers.discard(reader)

    def _publish(self) -> None:
        self._timer = None
        if not self._readers:
            return  # nobody watching: nothing to build, nothing to wake for
        self.robot.advance()
        record = self.robot.truth_record()
        record["host_time"] = time.time()  # the boards caught up with this instant
        line = (json.dumps(record, separators=(",", ":")) + "\n").encode()
        self.publications += 1
        for reader in list(self._readers):
            transport = reader.transport
            if transport is None or transport.is_closing():
                continue
            if transport.get_write_buffer_size() > TRUTH_BACKLOG_BYTES:
                self.aborted += 1  # not reading: let go now, its buffer with it
                transport.abort()
                continue
            transport.write(line)
        self._timer = asyncio.get_running_loop().call_later(TRUTH_PERIOD_S, self._publish)

    async def close(self) -> None:
        self.listener.close()
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        for reader in list(self._readers):
            if reader.transport is not None:
                reader.transport.abort()
        await self.stop_listening()


def error_line(text: str) -> bytes:
    """A JSON line a truth reader parses as an error rather than a pose."""
    return (json.dumps({"error": text}) + "\n").encode()

