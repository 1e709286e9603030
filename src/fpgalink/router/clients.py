"""A board's clients: over TCP (:class:`TcpClient`, connected from accept to close) or on a
pseudo-terminal slot (:class:`PtyClient`, connected while some process has it open). Each
reads what its client sends a slice at a time, cuts it into whole frames and hands them to
its board's route (:class:`ClientHost`); what the route sends it waits in the client's own
buffer, which the route bounds."""

from __future__ import annotations

import asyncio
import contextlib
import os
import select
import socket
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

from fpgalink.ports import PtyOutput, make_link, open_raw_pty, pty_where, remove_own_link
from fpgalink.protocol.framing import FrameDecoder, Framing
from fpgalink.router.stats import Client, ClientStats

__all__ = ["CLIENT_READ_SIZE", "PTY_POLL_S", "ClientHost", "PtyClient", "TcpClient"]

#: At most this many bytes of a client are read and handled at a time: a client's burst
#: (a megabyte written at once) is taken a slice at a time, the board's line, the other
#: clients and the signals served between slices.
CLIENT_READ_SIZE = 16384
#: How often a pty slot nobody has open is looked at for a client opening it, s.
PTY_POLL_S = 0.02


class ClientHost(Protocol):
    """What a client tells its board's route (:class:`~fpgalink.router.route.BoardRoute`)."""

    framing: Framing
    #: bytes a client may leave unread (its socket's send buffer is sized to it too)
    client_buffer: int

    def joined(self, client: Client, peer: str) -> None: ...

    def from_client(self, client: Client, contents: Sequence[bytes]) -> None: ...

    def left(self, client: Client) -> None: ...


class TcpClient(asyncio.BufferedProtocol):
    """A client over TCP: connected from accept to close."""

    def __init__(self, route: ClientHost) -> None:
        self.route = route
        self.transport: asyncio.Transport | None = None
        self.decoder = FrameDecoder(route.framing)
        self.stats = ClientStats(0, "")
        self._buffer = bytearray(CLIENT_READ_SIZE)

    def backlog(self) -> int | None:
        """Bytes written for it and not yet taken; ``None`` when it cannot take any."""
        transport = self.transport
        if transport is None or transport.is_closing():
            return None
        return transport.get_write_buffer_size()

    def send(self, wire: bytes) -> None:
        assert self.transport is not None
        self.transport.write(wire)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        # The kernel's send buffer counts towards what may wait for a client, or a client
        # that does not read would hold megabytes (loopback autotuning) before --client-
        # buffer applied at all.
        sock = transport.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self.route.client_buffer)
        peer = transport.get_extra_info("peername")
        self.route.joined(self, f"{peer[0]}:{peer[1]}" if peer else "?")

    def get_buffer(self, sizehint: int) -> memoryview:
        return memoryview(self._buffer)

    def buffer_updated(self, nbytes: int) -> None:
        items = self.decoder.feed(bytes(self._buffer[:nbytes]))
        self.route.from_client(self, [item for item in items if type(item) is bytes])
        self.stats.noise_bytes = self.decoder.stats.dropped_bytes

    def connection_lost(self, exc: Exception | None) -> None:
        self.route.left(self)


class PtyClient:
    """A client slot on a pseudo-terminal: a client is connected while some process has
    the slave side open (the master sees a hang-up otherwise); each opening is a new client.
    The router does not hold the slave open itself, so it sees a client leave. With
    ``link``, the slot is behind that stable symlink (:func:`fpgalink.ports.make_link`:
    :class:`~fpgalink.ports.LinkError` when it cannot be made), removed on :meth:`close`
    while it still points at this pty."""

    def __init__(self, route: ClientHost, link: Path | None = None) -> None:
        self.route = route
        self.master, slave, self.path = open_raw_pty()
        os.close(slave)
        #: the stable name clients open (--link), removed when the router stops
        self.link: Path | None = None
        if link is not None:
            try:
                make_link(link, self.path)
            except BaseException:
                os.close(self.master)
                raise
            self.link = link
        self.decoder = FrameDecoder(route.framing)
        self.stats = ClientStats(0, self.path)
        self.connected = False
        self._output = PtyOutput(self.master)
        self._poll = select.poll()
        self._poll.register(self.master, select.POLLIN | select.POLLHUP)
        self._timer: asyncio.TimerHandle | None = None

    def start(self) -> None:
        self._check()

    def _check(self) -> None:
        """Connected when the master no longer reports a hang-up; polled only while nobody
        has the slot (a connected client's leaving shows as a failed read)."""
        self._timer = None
        hung_up = any(events & select.POLLHUP for _, events in self._poll.poll(0))
        loop = asyncio.get_running_loop()
        if not hung_up:
            self.connected = True
            self.decoder = FrameDecoder(self.route.framing)
            self.route.joined(self, self.shown)
            loop.add_reader(self.master, self._readable)
            return
        self._timer = loop.call_later(PTY_POLL_S, self._check)

    def _readable(self) -> None:
        try:
            data = os.read(self.master, CLIENT_READ_SIZE)
        except BlockingIOError:
            return
        except OSError:  # EIO: the last process with the slave open closed it
            self._hang_up()
            return
        items = self.decoder.feed(data)
        self.route.from_client(self, [item for item in items if type(item) is bytes])
        self.stats.noise_bytes = self.decoder.stats.dropped_bytes

    def _hang_up(self) -> None:
        loop = asyncio.get_running_loop()
        loop.remove_reader(self.master)
        self._output.discard()  # what it did not read is not kept for the next client
        self.connected = False
        self.route.left(self)
        self._timer = loop.call_later(PTY_POLL_S, self._check)

    def backlog(self) -> int | None:
        return len(self._output.pending) if self.connected else None

    def send(self, wire: bytes) -> None:
        self._output.write(wire)

    def close(self) -> None:
        loop = asyncio.get_running_loop()
        if self._timer is not None:
            self._timer.cancel()
        with contextlib.suppress(Exception):
            loop.remove_reader(self.master)
        self._output.discard()
        with contextlib.suppress(OSError):
            os.close(self.master)
        if self.link is not None:
            # Only our own: another router may have taken the name since.
            remove_own_link(self.link, self.path)

    @property
    def shown(self) -> str:
        return pty_where(self.path, self.link)
