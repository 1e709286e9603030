"""A board on a TCP port (``fpgaemu serve --tcp``), one host at a time, as a serial port has
one owner."""

from __future__ import annotations

import asyncio
import contextlib
import socket

from fpgaemu.serving.bridge import TxBridge
from fpgaemu.serving.listening import ListeningEndpoint, turn_away
from fpgaemu.serving.loop import Pacer, say
from fpgaemu.serving.pacing import (
    RX_BACKLOG_BYTES,
    TX_BACKLOG_S,
    PacedBoard,
    RxFlow,
    earliest,
    schedule_unplugs,
)

__all__ = ["BUSY_GRACE_S", "BUSY_MESSAGE", "HOST_RCVBUF_BYTES", "IDLE_TIMEOUT_S",
           "NO_DESCRIPTOR_MESSAGE", "TcpEndpoint"]

#: How long a connection that arrives while another host is served waits for that host to
#: turn out to have left already (its last bytes still crossing), before it is turned away.
BUSY_GRACE_S = 0.5
#: What a second host is told before its connection is closed.
BUSY_MESSAGE = b"busy: another host is connected\n"
#: What a host is told when serve has no descriptor left for it.
NO_DESCRIPTOR_MESSAGE = b"busy: serve has no file descriptor left\n"
#: A TCP host that has sent nothing at all this long after connecting is disconnected
#: (``fpgaemu serve --idle-timeout``; 0 never): it holds the board from every other host.
#: A host that has sent anything keeps the board until it leaves, as a serial port's owner
#: does — a monitoring host sends nothing for long stretches while the board is disabled.
IDLE_TIMEOUT_S = 30.0
#: The kernel's receive buffer for a TCP host (doubled by Linux): what a departed host had
#: in flight is at most this, about 0.3 s of line at 1 MBd.
HOST_RCVBUF_BYTES = 16 * 1024


class _HostConnection(asyncio.BufferedProtocol):
    """A TCP host's connection: its bytes are received straight into a buffer no larger
    than the room the line has, so serve never holds more of them than the backlog."""

    def __init__(self, endpoint: TcpEndpoint) -> None:
        self.endpoint = endpoint
        self.transport: asyncio.Transport | None = None
        self.sent_anything = False
        self._buffer = bytearray(RX_BACKLOG_BYTES)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        self.endpoint.host_joined(self)

    def get_buffer(self, sizehint: int) -> memoryview:
        # At least one byte: a read is only asked for while the line had room.
        room = max(1, min(len(self._buffer), self.endpoint.paced.rx_room()))
        return memoryview(self._buffer)[:room]

    def buffer_updated(self, nbytes: int) -> None:
        self.sent_anything = True
        self.endpoint.host_bytes(bytes(self._buffer[:nbytes]))

    def eof_received(self) -> bool:
        return False  # the host is done: close

    def connection_lost(self, exc: Exception | None) -> None:
        self.endpoint.host_left(self)


class TcpEndpoint(ListeningEndpoint):
    """One board on a TCP port, one host at a time, as a serial port has one owner. A second
    host is told ``busy: another host is connected`` and disconnected (after
    :data:`BUSY_GRACE_S`, in case the first has just left). What a departed host wrote that
    the line had not begun to carry is discarded. Host bytes are read only as fast as the
    line carries them (the host's writes wait in its socket meanwhile); TX bytes a host does
    not read pile up to the same backlog a pty keeps, then the newest are dropped and
    counted. A host that sends nothing for ``idle_timeout`` seconds after connecting is
    told so and disconnected. The board's bytes are sent as a USB-UART bridge hands them
    over (:class:`~fpgaemu.serving.bridge.TxBridge`): a frame whole, as it ends."""

    def __init__(self, paced: PacedBoard, host: str, port: int, *,
                 idle_timeout: float = IDLE_TIMEOUT_S) -> None:
        super().__init__(host, port, NO_DESCRIPTOR_MESSAGE, rcvbuf=HOST_RCVBUF_BYTES)
        self.paced = paced
        self.idle_timeout = idle_timeout
        self.flow = RxFlow(paced, self._pause, self._resume)
        self.bridge = TxBridge(paced)
        self.pacer = Pacer(self._tick, self._next_wake)
        self._backlog = int(TX_BACKLOG_S * paced.board.config.baud / 10)
        self._connection: _HostConnection | None = None
        self._busy = False  #: a host is being connected or is connected
        self._free: asyncio.Event | None = None
        self._closing = False
        self._idle: asyncio.TimerHandle | None = None
        self.unplugged = False
        self.unplugs = 0
        self._port_when_unplugged = port
        self.connections = 0
        self.turned_away = 0  #: hosts told "busy"
        self.idle_closed = 0  #: hosts disconnected for sending nothing
        #: TX bytes lost because the host did not read them for longer than the backlog holds
        self.dropped_tx = 0

    async def start(self) -> None:
        self._free = asyncio.Event()
        self._free.set()
        self.listener.open()
        self.pacer.start()
        schedule_unplugs(self.paced, self._unplug, self._replug)

    def _unplug(self) -> None:
        """The link goes: the host's connection is closed and the port stops listening, so
        a host trying to reconnect is refused, as opening a pulled-out device fails, until
        it comes back on the same port."""
        if not self.unplugged:
            self.unplugged = True
            self.unplugs += 1
            self._port_when_unplugged = self.listener.port
            self.listener.close()
            self.unplug()
            say(f"unplugged {self.url}")

    def _replug(self) -> None:
        if not self.unplugged:
            return
        urls = self.listener.urls
        self.listener.requested_port = self._port_when_unplugged
        self.listener.urls = []
        try:
            self.listener.open()
        except OSError as exc:
            say(f"cannot listen on {urls[0] if urls else self.host} again: "
                f"{exc.strerror or exc}; the board stays unplugged")
            return
        finally:
            self.listener.urls = urls
        self.unplugged = False
        say(f"plugged in again: {self.url}")

    def accepted(self, connection: socket.socket) -> None:
        if self._closing or self.unplugged:
            connection.close()
        elif not self._busy:
            self._take(connection)
        else:
            self.spawn(self._when_free(connection))

    async def _when_free(self, connection: socket.socket) -> None:
        # Most often the host being served has just left and serve has not seen it yet.
        assert self._free is not None
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._free.wait(), BUSY_GRACE_S)
        if self._busy or self._closing:
            self.turned_away += 1
            turn_away(connection, BUSY_MESSAGE)
        else:
            self._take(connection)

    def _take(self, connection: socket.socket) -> None:
        assert self._free is not None
        self._busy = True
        self._free.clear()
        self.spawn(self._attach(connection))

    async def _attach(self, connection: socket.socket) -> None:
        if not await self.attach(connection, lambda: _HostConnection(self)):
            self._release()

    def host_joined(self, connection: _HostConnection) -> None:
        """A host's connection is made (its protocol says so)."""
        self._connection = connection
        self.connections += 1
        if self.idle_timeout > 0:
            self._idle = asyncio.get_running_loop().call_later(self.idle_timeout,
                                                               self._idle_out, connection)

    def _idle_out(self, connection: _HostConnection) -> None:
        self._idle = None
        if connection is self._connection and not connection.sent_anything and \
                connection.transport is not None:
            self.idle_closed += 1
            connection.transport.write(
                f"idle: nothing received in {self.idle_timeout:g} s; closing\n".encode())
            connection.transport.close()

    def host_bytes(self, data: bytes) -> None:
        """The host sent ``data`` (no more than the line had room for)."""
        if self._idle is not None:
            self._idle.cancel()
            self._idle = None
        self.paced.host_write(data)
        self.flow.took()
        self.pacer.poke()

    def _pause(self) -> None:
        connection = self._connection
        if connection is not None and connection.transport is not None:
            connection.transport.pause_reading()

    def _resume(self) -> None:
        connection = self._connection
        if connection is not None and connection.transport is not None and \
                not connection.transport.is_closing():
            connection.transport.resume_reading()

    def host_left(self, connection: _HostConnection) -> None:
        """A host's connection is gone: what it wrote that the line had not begun is
        discarded, and the board is free for the next."""
        if connection is not self._connection:
            return
        self._connection = None
        if self._idle is not None:
            self._idle.cancel()
            self._idle = None
        self.paced.host_gone()
        self.flow.reset()
        self._release()

    def _release(self) -> None:
        self._busy = False
        if self._free is not None:
            self._free.set()

    def unplug(self) -> None:
        """The board's side of the cable comes out: the host's connection is closed."""
        connection = self._connection
        if connection is not None and connection.transport is not None:
            connection.transport.close()

    @property
    def host_connected(self) -> bool:
        return self._connection is not None

    def _next_wake(self) -> float | None:
        return earliest(self.flow.next_wake(), self.bridge.next_wake())

    def _tick(self) -> None:
        self.paced.run()
        self.flow.check()
        out = self.bridge.take()
        connection = self._connection
        if out and connection is not None and connection.transport is not None and \
                not connection.transport.is_closing():
            transport = connection.transport
            if transport.get_write_buffer_size() + len(out) > self._backlog:
                self.dropped_tx += len(out)  # the host is not reading: like a wire, gone
                return
            transport.write(out)

    async def close(self) -> None:
        self._closing = True
        await self.pacer.stop()
        if self._idle is not None:
            self._idle.cancel()
        self.unplug()
        await self.stop_listening()

