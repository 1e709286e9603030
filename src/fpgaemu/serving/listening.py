"""Listening on TCP, shared by the boards' endpoints and the truth endpoint: the sockets of
one endpoint on every address a client can reach it by (:class:`Listener`), a descriptor
kept in reserve for a connection that comes when the process has none left, and what every
listening endpoint shares (:class:`ListeningEndpoint`: the addresses it prints, the
attaching of accepted connections, their tasks)."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import socket
from collections.abc import Callable, Coroutine
from typing import Any

from fpgaemu.serving.loop import say
from fpgalink.ports import usable_url

__all__ = ["Listener", "ListeningEndpoint", "requested_url", "turn_away"]

#: errno values that say a connection could not be accepted for want of a descriptor (or
#: the memory behind one).
_NO_DESCRIPTOR = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
#: Connections taken per wake-up of a listening socket, so one busy port does not hold up
#: the boards.
_ACCEPTS_PER_WAKE = 16


class _Spare:
    """One descriptor kept in reserve: a connection that arrives when the process has none
    left is still accepted with it — told why, and closed at once — instead of waking the
    loop again and again from the kernel's queue (the libev and nginx remedy)."""

    fd: int | None = None

    @classmethod
    def keep(cls) -> None:
        if cls.fd is None:
            with contextlib.suppress(OSError):
                cls.fd = os.open(os.devnull, os.O_RDONLY)

    @classmethod
    def refuse(cls, listening: socket.socket, message: bytes) -> bool:
        """Accept one waiting connection with the spare descriptor, tell it ``message`` and
        close it; ``False`` if there was no spare or nothing to accept."""
        if cls.fd is None:
            return False
        os.close(cls.fd)
        cls.fd = None
        try:
            connection, _ = listening.accept()
        except OSError:
            cls.keep()
            return False
        turn_away(connection, message)  # closed: its descriptor is the spare again
        cls.keep()
        return True


def turn_away(connection: socket.socket, message: bytes) -> None:
    """Tell a connection why it is not served (if its buffer takes it now) and close it."""
    with connection:
        connection.setblocking(False)
        with contextlib.suppress(OSError):
            connection.send(message)


def requested_url(host: str, port: int) -> str:
    """The address asked for, for a message (``*`` for every interface)."""
    shown = f"[{host}]" if ":" in host else host or "*"
    return f"socket://{shown}:{port}"


class Listener:
    """The listening sockets of one endpoint, one per address a client can reach it by: an
    empty ``host`` (``--tcp :PORT``) listens on IPv4 and IPv6 (each on every interface,
    the same port when it is free on both), a name on every address it resolves to.
    Connections go to ``accept`` as non-blocking sockets; one that arrives when the process
    has no descriptor left is turned away with ``starved`` and said once on stderr."""

    def __init__(self, host: str, port: int, accept: Callable[[socket.socket], None],
                 starved: bytes, *, rcvbuf: int | None = None, backlog: int = 16) -> None:
        self.host = host
        self.requested_port = port
        self._accept = accept
        self._starved_message = starved
        self._rcvbuf = rcvbuf
        self._backlog = backlog
        self.sockets: list[socket.socket] = []
        self.urls: list[str] = []
        #: connections turned away for want of a descriptor
        self.refused_no_descriptor = 0
        self._loop: asyncio.AbstractEventLoop | None = None

    def _addresses(self) -> list[tuple[int, str]]:
        if not self.host:
            wildcard: list[tuple[int, str]] = [(socket.AF_INET, "0.0.0.0")]
            if socket.has_ipv6:
                wildcard.append((socket.AF_INET6, "::"))
            return wildcard
        found: list[tuple[int, str]] = []
        for family, _, _, _, address in socket.getaddrinfo(
                self.host, self.requested_port, type=socket.SOCK_STREAM,
                flags=socket.AI_PASSIVE):
            entry: tuple[int, str] = (int(family), str(address[0]))
            if entry not in found:
                found.append(entry)
        return found

    def open(self) -> None:
        """Bind and listen; ``OSError`` (nothing left open) if an address cannot be served."""
        self._loop = asyncio.get_running_loop()
        _Spare.keep()
        addresses = self._addresses()
        port = self.requested_port
        try:
            for family, address in addresses:
                try:
                    sock = self._bind(family, address, port)
                except OSError as exc:
                    if self.requested_port == 0 and port and exc.errno == errno.EADDRINUSE:
                        sock = self._bind(family, address, 0)  # its own port, printed
                    elif not self.host and family == socket.AF_INET6 and exc.errno in (
                            errno.EAFNOSUPPORT, errno.EADDRNOTAVAIL) and self.sockets:
                        continue  # no IPv6 here: IPv4 alone
                    else:
                        raise
                bound = sock.getsockname()[1]
                port = port or bound
                self.sockets.append(sock)
                self.urls.append(usable_url(address, bound))
        except BaseException:
            self.close()
            raise
        for sock in self.sockets:
            self._loop.add_reader(sock.fileno(), self._readable, sock)

    def _bind(self, family: int, address: str, port: int) -> socket.socket:
        sock = socket.socket(family, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            if self._rcvbuf is not None:  # inherited by every accepted connection
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self._rcvbuf)
            sock.bind((address, port))
            sock.listen(self._backlog)
            sock.setblocking(False)
        except BaseException:
            sock.close()
            raise
        return sock

    @property
    def port(self) -> int:
        return int(self.sockets[0].getsockname()[1]) if self.sockets else self.requested_port

    def _readable(self, listening: socket.socket) -> None:
        for _ in range(_ACCEPTS_PER_WAKE):
            try:
                connection, _ = listening.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                if exc.errno in _NO_DESCRIPTOR:
                    self._starved(listening, exc)
                return  # a client that gave up first, or a passing error: next wake-up
            connection.setblocking(False)
            self._accept(connection)

    def _starved(self, listening: socket.socket, exc: OSError) -> None:
        say(f"out of file descriptors ({exc.strerror}): new connections are turned away "
            "until some close; the boards are still served", once="no descriptor")
        if _Spare.refuse(listening, self._starved_message):
            self.refused_no_descriptor += 1
            return
        # Not even the spare: stop watching this socket a moment rather than spin on it.
        loop = self._loop
        assert loop is not None
        loop.remove_reader(listening.fileno())
        loop.call_later(0.1, self._watch_again, listening)

    def _watch_again(self, listening: socket.socket) -> None:
        if listening in self.sockets and self._loop is not None:
            self._loop.add_reader(listening.fileno(), self._readable, listening)

    def close(self) -> None:
        for sock in self.sockets:
            if self._loop is not None:
                with contextlib.suppress(Exception):
                    self._loop.remove_reader(sock.fileno())
            sock.close()
        self.sockets = []


class ListeningEndpoint:
    """What a TCP endpoint (a board's, the truth's) shares: its :class:`Listener`, the
    ``socket://`` URLs a client uses, and the tasks that attach accepted connections.
    A subclass says what to do with each connection (:meth:`accepted`)."""

    def __init__(self, host: str, port: int, starved: bytes, *, rcvbuf: int | None = None,
                 backlog: int = 16) -> None:
        self.host = host
        self.listener = Listener(host, port, self.accepted, starved, rcvbuf=rcvbuf,
                                 backlog=backlog)
        self._tasks: set[asyncio.Task[None]] = set()

    @property
    def port(self) -> int:
        return self.listener.port

    @property
    def urls(self) -> list[str]:
        """A ``socket://`` URL per listening socket, each usable by a client."""
        return self.listener.urls or [requested_url(self.host, self.port)]

    @property
    def url(self) -> str:
        return self.urls[0]

    def accepted(self, connection: socket.socket) -> None:
        """A client connected (a non-blocking socket): serve it, or turn it away."""
        raise NotImplementedError

    def spawn(self, coro: Coroutine[Any, Any, None]) -> None:
        """Run ``coro`` as a task of this endpoint (cancelled by :meth:`stop_listening`)."""
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def attach(self, connection: socket.socket,
                     protocol_factory: Callable[[], asyncio.BaseProtocol]) -> bool:
        """Hand an accepted socket to the event loop with its protocol; ``False`` (the
        socket closed) when that fails: the client had gone already."""
        try:
            await asyncio.get_running_loop().connect_accepted_socket(protocol_factory,
                                                                     connection)
        except OSError:
            connection.close()
            return False
        return True

    async def stop_listening(self) -> None:
        """No more connections: the sockets closed, the attaching tasks cancelled."""
        self.listener.close()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
