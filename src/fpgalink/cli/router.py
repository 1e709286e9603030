"""``router``: one process owns the boards' ports and offers each board to several local
clients, as mavlink-router does for a MAVLink vehicle, so ``monitor --passive`` or
``record --passive`` can watch while ``drive`` or ``step`` commands.

Each board gets a TCP port on loopback (``socket://127.0.0.1:PORT``, which ``open_link``
and every command take as ``--port``), and with ``--pty N`` N pseudo-terminals, one client
each (a client is connected while it has the pty open); ``--link NAME=PATH`` adds a pty
behind a stable symlink. Arbitration (docs/cli.md, ``router``):

* every client receives every whole frame the board sends, in order;
* the first client to send a frame is the board's **controller**: its frames go to the
  board; the others are **observers**: every frame they send is refused (not passed on) and
  counted, and the router says so on stderr the first time. When the controller leaves, the
  router sends ``RD`` (a motor is never left driven by a client that went away) and the next
  client to send becomes the controller;
* a client that does not read falls behind alone: once its socket's buffer holds more than
  ``--client-buffer`` bytes, the board's frames are dropped for it (whole frames, counted),
  never for the others and never by stalling the board's line.

Every count is exact per client and printed when the client leaves and when the router
stops (``--format json`` for scripts). Noise and broken frames on the board's line are
counted by the router and not passed on; clients' links see only whole frames.

A board's port that goes away (a USB-UART pulled out, a TCP board gone) is reopened with
backoff while the clients stay connected: to them it is a silence, which their links judge
by what the board sends when it is heard again (back or restarted), as on a cable cut."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import os
import select
import socket
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import click

from fpgalink.cli.formats import Column, emit_document, emit_rows, format_option
from fpgalink.cli.options import ConnectionOptions, connection_options
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, echo_out, note
from fpgalink.cli.session import install_stop_signals, run
from fpgalink.errors import PortError
from fpgalink.protocol.framing import DEFAULT_FRAMING, FrameDecoder, encode_frame

__all__ = ["BoardRoute", "ClientStats", "router"]

#: Loopback only: the router is for the clients on this machine (a remote client would
#: reach a motor controller over the network without any authentication).
HOST = "127.0.0.1"
DISABLE = encode_frame(b"RD", DEFAULT_FRAMING)
#: First and longest wait between tries to reopen a board's port that went away, s: a
#: USB-UART plugged back in is found within a quarter second, and a port that stays away
#: costs four failed opens a second.
REOPEN_BACKOFF = (0.05, 0.25)


@dataclass
class ClientStats:
    """One client's exact accounting."""

    client: int  #: the client's number on this board, from 1
    peer: str
    role: str = "observer"
    frames_to_client: int = 0  #: the board's frames delivered to it
    bytes_to_client: int = 0
    dropped_frames: int = 0  #: the board's frames not delivered: its buffer was full
    frames_to_board: int = 0  #: its frames passed to the board (as the controller)
    to_board_by_id: Counter[str] = field(default_factory=Counter)
    refused_frames: int = 0  #: its frames not passed on (an observer's writes)
    refused_by_id: Counter[str] = field(default_factory=Counter)
    #: its frames as the controller while the board's port was gone: not sent, nowhere to
    unsent_frames: int = 0
    noise_bytes: int = 0  #: bytes it sent that were not part of a whole frame
    connected: bool = True


class _Client(asyncio.Protocol):
    """A client over TCP: connected from accept to close."""

    def __init__(self, route: BoardRoute) -> None:
        self.route = route
        self.transport: asyncio.Transport | None = None
        self.decoder = FrameDecoder(route.framing)
        self.stats = ClientStats(0, "")

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

    def data_received(self, data: bytes) -> None:
        for item in self.decoder.feed(data):
            if isinstance(item, bytes):
                self.route.from_client(self, item)
        self.stats.noise_bytes = self.decoder.stats.dropped_bytes

    def connection_lost(self, exc: Exception | None) -> None:
        self.route.left(self)


#: How often a pty slot nobody has open is looked at for a client opening it, s.
PTY_POLL_S = 0.02


class _PtyClient:
    """A client slot on a pseudo-terminal: a client is connected while some process has
    the slave side open (the master sees a hang-up otherwise); each opening is a new client.
    The router does not hold the slave open itself, so it sees a client leave."""

    def __init__(self, route: BoardRoute, link: Path | None = None) -> None:
        import tty

        self.route = route
        self.master, slave = os.openpty()
        tty.setraw(slave)  # kept by the pty: nothing echoes before the client sets it up
        self.path = os.ttyname(slave)
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
        os.set_blocking(self.master, False)
        self.decoder = FrameDecoder(route.framing)
        self.stats = ClientStats(0, self.path)
        self.connected = False
        self._out = bytearray()
        self._writing = False
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
            data = os.read(self.master, 65536)
        except BlockingIOError:
            return
        except OSError:  # EIO: the last process with the slave open closed it
            self._hang_up()
            return
        for item in self.decoder.feed(data):
            if isinstance(item, bytes):
                self.route.from_client(self, item)
        self.stats.noise_bytes = self.decoder.stats.dropped_bytes

    def _hang_up(self) -> None:
        loop = asyncio.get_running_loop()
        loop.remove_reader(self.master)
        if self._writing:
            loop.remove_writer(self.master)
            self._writing = False
        self._out.clear()  # what it did not read is not kept for the next client
        self.connected = False
        self.route.left(self)
        self._timer = loop.call_later(PTY_POLL_S, self._check)

    def backlog(self) -> int | None:
        return len(self._out) if self.connected else None

    def send(self, wire: bytes) -> None:
        self._out += wire
        self._flush()

    def _flush(self) -> None:
        try:
            written = os.write(self.master, self._out)
            del self._out[:written]
        except BlockingIOError:
            pass
        except OSError:
            pass  # hung up: the next read says so
        loop = asyncio.get_running_loop()
        if self._out and not self._writing:
            loop.add_writer(self.master, self._flush)
            self._writing = True
        elif not self._out and self._writing:
            loop.remove_writer(self.master)
            self._writing = False

    def close(self) -> None:
        loop = asyncio.get_running_loop()
        if self._timer is not None:
            self._timer.cancel()
        with contextlib.suppress(Exception):
            loop.remove_reader(self.master)
        with contextlib.suppress(Exception):
            loop.remove_writer(self.master)
        with contextlib.suppress(OSError):
            os.close(self.master)
        if self.link is not None:
            with contextlib.suppress(OSError):
                # Only our own: another router may have taken the name since.
                if os.readlink(self.link) == self.path:
                    self.link.unlink()

    @property
    def shown(self) -> str:
        return self.path if self.link is None else f"{self.link} -> {self.path}"


def make_link(path: Path, target: str) -> None:
    """A symlink at ``path`` to ``target``. One left by an earlier router killed before it
    could remove it (its pty is gone, or is now ours) is replaced; a symlink to a pty that
    is there may be another router's or ``fpgaemu serve``'s, live, and is not touched;
    nor is anything else."""
    if path.is_symlink():
        pointed = os.readlink(path)
        if pointed != target and os.path.exists(path):
            raise CliError(f"--link {path}: a symlink to {pointed}, which exists (another "
                           "router or fpgaemu serve may be serving it); not replacing it — "
                           "remove it if it is stale", ExitCode.BAD_INPUT)
        path.unlink()
    elif path.exists():
        raise CliError(f"--link {path}: exists and is not a symlink; not replacing it",
                       ExitCode.BAD_INPUT)
    try:
        path.symlink_to(target)
    except OSError as exc:
        raise CliError(f"--link {path}: {exc.strerror or exc}", ExitCode.PORT) from None


def parse_links(values: tuple[str, ...], names: list[str]) -> list[tuple[str, Path]]:
    """``--link PATH`` (one board) or ``--link NAME=PATH``; a board may have several."""
    links: list[tuple[str, Path]] = []
    for value in values:
        name, sep, path = value.partition("=")
        if not sep:
            if len(names) != 1:
                raise CliError(f"--link {value!r}: with several boards give NAME=PATH, "
                               f"NAME one of {', '.join(names)}", ExitCode.BAD_INPUT)
            name, path = names[0], value
        if name not in names:
            raise CliError(f"--link {value!r}: no board named {name!r} (boards: "
                           f"{', '.join(names)})", ExitCode.BAD_INPUT)
        if not path:
            raise CliError(f"--link {value!r}: no path", ExitCode.BAD_INPUT)
        links.append((name, Path(path)))
    taken = [str(path) for _, path in links]
    if len(set(taken)) != len(taken):
        raise CliError("--link: the same path twice", ExitCode.BAD_INPUT)
    return links


class _Board(asyncio.Protocol):
    def __init__(self, route: BoardRoute) -> None:
        self.route = route
        self.lost: asyncio.Future[Exception | None] = \
            asyncio.get_running_loop().create_future()

    def data_received(self, data: bytes) -> None:
        self.route.from_board(data)

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.lost.done():
            self.lost.set_result(exc)


@dataclass
class BoardRoute:
    """One board's port shared among its clients."""

    name: str
    url: str
    client_buffer: int
    framing: Any = DEFAULT_FRAMING
    board: asyncio.BaseTransport | None = None
    #: resolved when the board's port goes away (set anew each time it is opened)
    lost: asyncio.Future[Exception | None] | None = None
    decoder: FrameDecoder = field(default_factory=lambda: FrameDecoder(DEFAULT_FRAMING))
    clients: list[_Client | _PtyClient] = field(default_factory=list)
    controller: _Client | _PtyClient | None = None
    ptys: list[_PtyClient] = field(default_factory=list)
    history: list[ClientStats] = field(default_factory=list)
    frames_from_board: int = 0
    board_framing_errors: int = 0
    next_client: int = 1
    #: RD sent because the controller left (or the router stopped with one connected)
    disables_sent: int = 0
    #: the controller left while the port was gone: RD goes first when it is back
    disable_pending: bool = False
    port_losses: int = 0
    reconnects: int = 0
    #: the board's frames cut short by its port going away (neither passed on nor counted
    #: as a framing error: the line was cut, not garbled)
    frames_cut: int = 0
    lost_since: float | None = None  #: monotonic time the port went away, while it is away
    #: -v: each enable and disable a client passes to the board is said, as it happens
    #: (who enabled the motor, and whether it disabled it before it left)
    verbose: int = 0
    server: asyncio.Server | None = None

    # --- the board ----------------------------------------------------------------------

    async def open(self, baud: int) -> None:
        """Open the board's port (:class:`PortError` when it cannot be)."""
        from fpgalink.aio.transport import open_transport

        holder: list[_Board] = []

        def factory() -> _Board:
            holder.append(_Board(self))
            return holder[-1]

        self.board, _ = await open_transport(self.url, baud, factory)
        self.lost = holder[0].lost

    def port_lost(self, exc: Exception | None) -> None:
        self.board = None
        self.port_losses += 1
        # A frame the board had begun when its port went is not joined to the bytes of
        # the port opened next.
        if self.decoder.pending:
            self.frames_cut += 1
        self.decoder = FrameDecoder(self.framing)
        self.lost_since = time.monotonic()
        cause = str(exc) if exc else "closed by the other end"
        note(f"board {self.name}: port {self.url} lost ({cause})")

    def port_back(self, tries: int) -> None:
        away = time.monotonic() - (self.lost_since or time.monotonic())
        self.lost_since = None
        self.reconnects += 1
        note(f"board {self.name}: port {self.url} back after {away:.1f} s "
             f"({tries} {'try' if tries == 1 else 'tries'}); its clients stayed connected")
        # The controller that left while the port was gone may have left the board enabled
        # (an outage shorter than its 300 ms watchdog): RD goes first, whoever controls it
        # now. A new controller's frames sent during the outage were not delivered; its
        # next RE enables the board again.
        if self.disable_pending and self.to_board(DISABLE):
            self.disables_sent += 1
            self.disable_pending = False
            note(f"board {self.name}: RD sent for the controller that left while the port "
                 "was gone")

    def from_board(self, data: bytes) -> None:
        for item in self.decoder.feed(data):
            if not isinstance(item, bytes):
                self.board_framing_errors += 1
                continue
            self.frames_from_board += 1
            wire = encode_frame(item, self.framing)
            for client in self.clients:
                backlog = client.backlog()
                if backlog is None:
                    continue
                if backlog > self.client_buffer:
                    client.stats.dropped_frames += 1
                    continue
                client.send(wire)
                client.stats.frames_to_client += 1
                client.stats.bytes_to_client += len(wire)

    def to_board(self, wire: bytes) -> bool:
        """Whether the board's port took ``wire`` (not while it is gone)."""
        board = self.board
        if isinstance(board, asyncio.WriteTransport) and not board.is_closing():
            board.write(wire)
            return True
        return False

    # --- the clients --------------------------------------------------------------------

    def joined(self, client: _Client | _PtyClient, peer: str) -> None:
        client.stats = ClientStats(self.next_client, peer)
        self.next_client += 1
        self.clients.append(client)
        self.history.append(client.stats)
        note(f"board {self.name}: client #{client.stats.client} connected ({peer})")

    def from_client(self, client: _Client | _PtyClient, content: bytes) -> None:
        stats = client.stats
        if self.controller is None:
            self.controller = client
            stats.role = "controller"
            note(f"board {self.name}: client #{stats.client} ({stats.peer}) is the "
                 "controller")
        if client is self.controller:
            if self.to_board(encode_frame(content, self.framing)):
                stats.frames_to_board += 1
                message_id = _message_id(content)
                stats.to_board_by_id[message_id] += 1
                if self.verbose and message_id in ("RE", "RD"):
                    note(f"board {self.name}: client #{stats.client} sent {message_id}")
            else:
                stats.unsent_frames += 1
            return
        message_id = _message_id(content)
        if stats.refused_frames == 0:
            note(f"board {self.name}: client #{stats.client} is an observer: its {message_id} "
                 f"was refused (client #{self.controller.stats.client} controls the board); "
                 "run it with --passive, or after the controller")
        stats.refused_frames += 1
        stats.refused_by_id[message_id] += 1

    def left(self, client: _Client | _PtyClient) -> None:
        with contextlib.suppress(ValueError):
            self.clients.remove(client)
        stats = client.stats
        stats.connected = False
        if client is self.controller:
            self.controller = None
            # The board is not left driven by a client that is gone.
            if self.to_board(DISABLE):
                self.disables_sent += 1
            else:
                self.disable_pending = True
        note(f"board {self.name}: client #{stats.client} ({stats.role}) left: "
             f"{stats.frames_to_client} frames to it, {stats.dropped_frames} dropped, "
             f"{stats.frames_to_board} to the board, {stats.refused_frames} refused")


def _message_id(content: bytes) -> str:
    """The frame's message ID as it is counted: the first two bytes (``E``, a heartbeat, is
    one letter and its counter)."""
    return content[:1].decode("ascii", "replace") if content[:1] == b"E" else \
        content[:2].decode("ascii", "replace")


def _rows(routes: list[BoardRoute]) -> list[dict[str, Any]]:
    rows = []
    for route in routes:
        for stats in route.history:
            row = dataclasses.asdict(stats)
            row["refused_by_id"] = dict(stats.refused_by_id)
            row["to_board_by_id"] = dict(stats.to_board_by_id)
            rows.append({"board": route.name, **row})
    return rows


SUMMARY_COLUMNS = (
    Column("board", "board"), Column("client", "client", justify="right"),
    Column("role", "role"), Column("peer", "peer", drop=2),
    Column("frames_to_client", "frames to it", justify="right"),
    Column("dropped_frames", "dropped", justify="right"),
    Column("frames_to_board", "to board", justify="right"),
    Column("refused_frames", "refused", justify="right"),
    Column("unsent_frames", "unsent", justify="right", drop=3),
    Column("bytes_to_client", "bytes to it", justify="right", drop=1),
)


@click.command(epilog=EXIT_CODES_HELP)
@click.option("--tcp", "first_port", type=click.IntRange(0, 65535), default=0,
              show_default=True,
              help="TCP port of the first board on 127.0.0.1, the next board's one more; 0: "
                   "any free ports (the ready lines say which).")
@click.option("--pty", "ptys", type=click.IntRange(0, 16), default=0, show_default=True,
              help="Also offer each board on this many pseudo-terminals, one client each "
                   "(a path such as /dev/pts/7, given as --port).")
@click.option("--link", "links", multiple=True, metavar="[NAME=]PATH",
              help="A pseudo-terminal for board NAME behind a stable symlink PATH (as "
                   "fpgaemu serve --link), one client at a time; repeatable, removed on "
                   "exit.")
@click.option("--reconnect/--no-reconnect", default=True, show_default=True,
              help="Reopen a board's port that goes away (unplugged) while its clients "
                   "stay connected; with --no-reconnect the router stops (exit 5).")
@click.option("--client-buffer", type=click.IntRange(4096, 1 << 30), default=1 << 20,
              show_default=True,
              help="Bytes a client may leave unread before the board's frames are dropped "
                   "for it (counted).")
@format_option
@connection_options(multi=True)
def router(first_port: int, ptys: int, links: tuple[str, ...], reconnect: bool,
           client_buffer: int, fmt: str, conn: ConnectionOptions) -> int:
    """Share each board among several local clients: one controller, observers read-only.

    Opens every board's port (--port NAME=URL, repeatable) and serves each on
    127.0.0.1 over TCP, printing "ready NAME socket://127.0.0.1:PORT" once all are served
    (and "ready NAME PATH -> /dev/pts/N" for each --link); give that URL or PATH as --port
    to any command or to open_link. Every client receives every frame its board sends.
    The first client to send is the controller; frames from the others are refused and
    counted (run watchers with --passive). When the controller leaves, the board gets
    RD. A board's port that goes away is reopened until it is back. -v says each RE and
    RD a client passes. Ctrl-C or SIGTERM stops the router and prints each client's counts
    (frames delivered, dropped for a full buffer, passed, refused).
    """
    routes = [BoardRoute(e.name, e.url, client_buffer, verbose=conn.verbose)
              for e in conn.endpoints]
    slots = parse_links(links, [r.name for r in routes])
    code = run(_route(conn, routes, first_port, ptys, slots, reconnect),
               ", ".join(r.url for r in routes))
    rows = _rows(routes)
    if fmt == "json":
        emit_document({"boards": [{"board": r.name, "url": r.url,
                                   "frames_from_board": r.frames_from_board,
                                   "board_framing_errors": r.board_framing_errors,
                                   "frames_cut": r.frames_cut,
                                   "disables_sent": r.disables_sent,
                                   "port_losses": r.port_losses,
                                   "reconnects": r.reconnects}
                                  for r in routes], "clients": rows})
    else:
        emit_rows(fmt, SUMMARY_COLUMNS, rows, title="Router clients")
    for route in routes:
        if route.port_losses:
            note(f"board {route.name}: its port went away {route.port_losses} time(s) and "
                 f"came back {route.reconnects} time(s)")
    return code


async def _route(conn: ConnectionOptions, routes: list[BoardRoute], first_port: int,
                 ptys: int, links: list[tuple[str, Path]], reconnect: bool) -> int:
    stop = asyncio.Event()
    install_stop_signals(stop)
    try:
        for index, route in enumerate(routes):
            await route.open(conn.baud)
            port = first_port + index if first_port else 0
            try:
                route.server = await asyncio.get_running_loop().create_server(
                    lambda route=route: _Client(route), HOST, port)  # type: ignore[misc]
            except OSError as exc:
                raise CliError(f"board {route.name}: cannot listen on {HOST}:{port}: "
                               f"{exc.strerror or exc}", ExitCode.PORT) from None
            try:
                for _ in range(ptys):
                    route.ptys.append(_PtyClient(route))
                for name, path in links:
                    if name == route.name:
                        route.ptys.append(_PtyClient(route, path))
            except OSError as exc:
                raise CliError(f"board {route.name}: cannot make a pty: "
                               f"{exc.strerror or exc}", ExitCode.PORT) from None
        for route in routes:
            assert route.server is not None
            port = route.server.sockets[0].getsockname()[1]
            echo_out(f"ready {route.name} socket://{HOST}:{port}")
            for slot in route.ptys:
                echo_out(f"ready {route.name} {slot.shown}")
                slot.start()
        kept = [asyncio.ensure_future(_keep(route, conn.baud, reconnect)) for route in routes]
        stopped: asyncio.Future[Any] = asyncio.ensure_future(stop.wait())
        done, _ = await asyncio.wait([stopped, *kept], return_when=asyncio.FIRST_COMPLETED)
        for future in (stopped, *kept):
            future.cancel()
        gone = [r for r, f in zip(routes, kept, strict=True) if f in done]
        for route in gone:
            note(f"board {route.name}: its port {route.url} closed: the router stops "
                 "(--no-reconnect)")
        return ExitCode.PORT if gone else ExitCode.OK
    finally:
        await _close(routes)


async def _keep(route: BoardRoute, baud: int, reconnect: bool) -> None:
    """Returns only when the board's port went away for good (--no-reconnect)."""
    while True:
        assert route.lost is not None
        route.port_lost(await route.lost)
        if not reconnect:
            return
        delay, ceiling = REOPEN_BACKOFF
        tries = 0
        while True:
            await asyncio.sleep(delay)
            tries += 1
            try:
                await route.open(baud)
            except PortError:
                delay = min(2 * delay, ceiling)
                continue
            route.port_back(tries)
            break


async def _close(routes: list[BoardRoute]) -> None:
    for route in routes:
        if route.server is not None:
            route.server.close()
        if route.controller is not None:
            route.controller = None
            if route.to_board(DISABLE):
                route.disables_sent += 1
        for client in list(route.clients):
            if isinstance(client, _Client):
                client.close()
        for slot in route.ptys:
            slot.close()
    for route in routes:
        if route.board is not None:
            route.board.close()
        if route.server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(route.server.wait_closed(), 1.0)
