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
  counted, and the router says so on stderr the first time; a refused ``PS`` or ``PG`` is
  answered ``PN`` 5 (another client controls the board), which the client's link raises as
  ``ParameterRefused``; an observer's ``IQ`` (who is the board?) is the one frame passed
  on: it changes nothing, and its ``IA`` reaches every client. When the controller leaves,
  the router sends ``RD`` at once, ahead of whatever of its frames still waits for the line
  (dropped, counted), so a motor is never left driven by a client that went away; the next
  client to send becomes the controller;
* what waits for the board is bounded by line time: the controller's frames are handed to
  the port at the line's pace (:class:`LineQueue`), at most :data:`BOARD_QUEUE_S` of line
  time waiting; a frame beyond that is refused and counted, and said on stderr;
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
import math
import os
import select
import socket
import time
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

import click

from fpgalink.cli.formats import Column, emit_document, emit_rows, format_option
from fpgalink.cli.options import ConnectionOptions, connection_options
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, echo_out, note
from fpgalink.cli.session import install_stop_signals, run
from fpgalink.errors import PortError
from fpgalink.protocol.catalogue import (
    IdentityQuery,
    NackReason,
    ParamGet,
    ParamNack,
    ParamSet,
    encode_message,
    parse_content,
)
from fpgalink.protocol.counter import SendCounter
from fpgalink.protocol.crc import append_crc, strip_crc
from fpgalink.protocol.framing import DEFAULT_FRAMING, FrameDecoder, encode_frame

__all__ = ["BOARD_QUEUE_S", "BoardRoute", "ClientStats", "LineQueue", "router"]

T = TypeVar("T")

#: Loopback only: the router is for the clients on this machine (a remote client would
#: reach a motor controller over the network without any authentication).
HOST = "127.0.0.1"
DISABLE = encode_frame(b"RD", DEFAULT_FRAMING)
#: First and longest wait between tries to reopen a board's port that went away, s: a
#: USB-UART plugged back in is found within a quarter second, and a port that stays away
#: costs four failed opens a second.
REOPEN_BACKOFF = (0.05, 0.25)
#: At most this much line time waits for a board (handed to its port and not yet on the
#: wire, or queued here): 20,000 bytes at 1 MBd. A controller writing faster than the line
#: carries has the excess refused and counted, and its RD (or the router's, when it leaves)
#: is never more than this behind.
BOARD_QUEUE_S = 0.2
#: The controller's frames are handed to the port while what was handed before has less
#: than this much line time left to go: the line never idles for want of a frame, and what
#: the port's driver holds (which nothing can overtake) stays this short.
LINE_LEAD_S = 0.02
#: A controller whose frames are refused for a full line is told on stderr at most this
#: often (with the count so far), s.
FULL_NOTE_EVERY_S = 2.0


class LineQueue(Generic[T]):
    """What waits for one board's line, paced by line time (sans-I/O: time passed in).

    :meth:`push` queues a frame (O(1)), or refuses it when :data:`BOARD_QUEUE_S` of line
    time would then wait in all — queued here, or handed out and not yet on the wire.
    :meth:`take` hands out, in order, what may go to the port now: frames while what was
    handed before has less than :data:`LINE_LEAD_S` left to go. :meth:`wake_at` says when
    to take again. :meth:`overtake` puts a frame (``RD``) ahead of everything waiting, which
    is dropped and returned: nothing queued before a disable may follow it."""

    def __init__(self, baud: int, bound: float = BOARD_QUEUE_S, lead: float = LINE_LEAD_S
                 ) -> None:
        self.byte_time = 10 / baud  #: 8N1: ten bit times a byte
        self.bound = bound
        self.lead = lead
        self._waiting: deque[tuple[T, int]] = deque()
        self._waiting_bytes = 0
        self._free_at = -math.inf  #: when what was handed out will have left the line

    def __len__(self) -> int:
        return len(self._waiting)

    def in_flight(self, now: float) -> float:
        """Line time still to go of what was handed out, s."""
        return max(0.0, self._free_at - now)

    def backlog(self, now: float) -> float:
        """Line time of everything not yet on the wire, handed out or waiting, s."""
        return self.in_flight(now) + self._waiting_bytes * self.byte_time

    def room(self, now: float) -> int:
        """Wire bytes that may still be pushed now."""
        return max(0, int((self.bound - self.backlog(now)) / self.byte_time + 1e-6))

    def full(self, size: int, now: float) -> bool:
        """Whether a frame of ``size`` wire bytes would take the backlog past the bound."""
        # (A nanosecond's slack: a bound filled exactly is not exceeded by rounding.)
        return self.backlog(now) + size * self.byte_time > self.bound + 1e-9

    def push(self, item: T, size: int, now: float) -> bool:
        """Queue ``item`` (``size`` wire bytes); ``False``: refused, the line is full."""
        if self.full(size, now):
            return False
        self._waiting.append((item, size))
        self._waiting_bytes += size
        return True

    def take(self, now: float) -> list[T]:
        """What goes to the port now, in order."""
        out: list[T] = []
        waiting = self._waiting
        free = max(self._free_at, now)
        while waiting and free - now < self.lead:
            item, size = waiting.popleft()
            self._waiting_bytes -= size
            free += size * self.byte_time
            out.append(item)
        if out:
            self._free_at = free
        return out

    def wake_at(self) -> float | None:
        """When :meth:`take` has something again (``None``: nothing waits)."""
        return self._free_at - self.lead / 2 if self._waiting else None

    def overtake(self, size: int, now: float) -> list[T]:
        """A frame of ``size`` bytes goes to the port now, ahead of everything waiting;
        returns what waited, dropped."""
        dropped = self.clear()
        self._free_at = max(self._free_at, now) + size * self.byte_time
        return dropped

    def clear(self) -> list[T]:
        """Drop everything waiting (returned, oldest first)."""
        dropped = [item for item, _ in self._waiting]
        self._waiting.clear()
        self._waiting_bytes = 0
        return dropped

    def reset(self) -> list[T]:
        """A new port (the old one went away): nothing is on its line; what waited is
        dropped and returned."""
        self._free_at = -math.inf
        return self.clear()


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
    #: its frames as the controller refused because BOARD_QUEUE_S of line time already
    #: waited for the board (it wrote faster than the line carries)
    line_full_frames: int = 0
    #: its frames still waiting for the line when an RD went ahead of them (its own, or the
    #: router's when it left): dropped, never sent
    overtaken_frames: int = 0
    noise_bytes: int = 0  #: bytes it sent that were not part of a whole frame
    connected: bool = True
    connected_s: float = 0.0  #: how long it was connected (once it has left), s


#: At most this many bytes of a client are read and handled at a time: a client's burst
#: (a megabyte written at once) is taken a slice at a time, the board's line, the other
#: clients and the signals served between slices.
CLIENT_READ_SIZE = 16384


class _Client(asyncio.BufferedProtocol):
    """A client over TCP: connected from accept to close."""

    def __init__(self, route: BoardRoute) -> None:
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
    #: the line's bit rate: what waits for the board is paced and bounded in its time
    baud: int = 1_000_000
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
    #: the controller's frames waiting for the line: (its stats, message ID, wire bytes)
    line: LineQueue[tuple[ClientStats, str, bytes]] = field(init=False)
    #: when each connected client joined (loop time), by client number
    joined_at: dict[int, float] = field(default_factory=dict)
    #: the router's own counter toward each client it answers (PN 5), by client number
    answer_counters: dict[int, SendCounter] = field(default_factory=dict)
    _pump_timer: asyncio.TimerHandle | None = field(default=None, init=False, repr=False)
    _full_said_at: float = field(default=-math.inf, init=False, repr=False)

    def __post_init__(self) -> None:
        self.line = LineQueue(self.baud)

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
        # What waited for the line has nowhere to go: not sent, counted.
        for stats, _, _ in self.line.reset():
            stats.unsent_frames += 1
        self._stop_pump()
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
        if self.disable_pending and self.disable_now(None):
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
                if self._deliver(client, wire):
                    client.stats.frames_to_client += 1
                    client.stats.bytes_to_client += len(wire)

    def _deliver(self, client: _Client | _PtyClient, wire: bytes) -> bool:
        """Hand ``wire`` to ``client`` unless its buffer is full (then counted dropped)."""
        backlog = client.backlog()
        if backlog is None:
            return False
        if backlog > self.client_buffer:
            client.stats.dropped_frames += 1
            return False
        client.send(wire)
        return True

    def _writable(self) -> asyncio.WriteTransport | None:
        board = self.board
        if isinstance(board, asyncio.WriteTransport) and not board.is_closing():
            return board
        return None

    def to_board(self, stats: ClientStats, contents: Sequence[bytes]) -> None:
        """A controller's frames toward the board, in order: queued for the line (paced by
        line time), refused when the line is full, unsent while the port is gone; an ``RD``
        goes at once, ahead of everything waiting."""
        if self._writable() is None:
            stats.unsent_frames += len(contents)
            return
        line, framing = self.line, self.framing
        now = asyncio.get_running_loop().time()
        room = line.room(now)
        refused = 0
        for content in contents:
            if content == b"RD":
                self.disable_now(stats)
                room = line.room(now)
                continue
            # Refused before it is encoded when even unescaped it would not fit: a flood's
            # excess costs as little as it can.
            if len(content) + 2 > room:
                refused += 1
                continue
            wire = encode_frame(content, framing)
            if not line.push((stats, _message_id(content), wire), len(wire), now):
                refused += 1
                continue
            room -= len(wire)
        if refused:
            stats.line_full_frames += refused
            self._say_full(stats, now)
        if self._pump_timer is None:  # else the line is busy: the timer hands it on
            self._pump()

    def disable_now(self, owner: ClientStats | None) -> bool:
        """``RD`` to the board at once, ahead of every frame waiting for the line (dropped
        and counted: nothing queued before a disable may follow it). ``owner``: the
        controller that sent it; ``None``: the router's own. Whether the port took it."""
        board = self._writable()
        if board is None:
            return False
        now = asyncio.get_running_loop().time()
        ahead = self.line.in_flight(now)
        overtaken = self.line.overtake(len(DISABLE), now)
        self._stop_pump()
        board.write(DISABLE)
        for stats, _, _ in overtaken:
            stats.overtaken_frames += 1
        if owner is None:
            self.disables_sent += 1
        else:
            self._passed(owner, "RD")
        if overtaken:
            note(f"board {self.name}: RD sent ahead of {len(overtaken):,} queued frame(s) "
                 f"of client #{overtaken[0][0].client} (dropped, counted); "
                 f"{ahead * 1000:.0f} ms of line time was already on its way")
        return True

    def _pump(self) -> None:
        """Hand the port what the line has room for now; come back when it has more."""
        self._pump_timer = None
        board = self._writable()
        if board is None:
            return
        loop = asyncio.get_running_loop()
        taken = self.line.take(loop.time())
        if taken:
            board.write(b"".join(wire for _, _, wire in taken))
            for stats, message_id, _ in taken:
                self._passed(stats, message_id)
        wake = self.line.wake_at()
        if wake is not None and self._pump_timer is None:
            self._pump_timer = loop.call_at(wake, self._pump)

    def _stop_pump(self) -> None:
        if self._pump_timer is not None:
            self._pump_timer.cancel()
            self._pump_timer = None

    def _passed(self, stats: ClientStats, message_id: str) -> None:
        stats.frames_to_board += 1
        stats.to_board_by_id[message_id] += 1
        if self.verbose and message_id in ("RE", "RD"):
            note(f"board {self.name}: client #{stats.client} sent {message_id}")

    def _say_full(self, stats: ClientStats, now: float) -> None:
        if now - self._full_said_at < FULL_NOTE_EVERY_S:
            return
        self._full_said_at = now
        note(f"board {self.name}: client #{stats.client} writes faster than the line "
             f"carries: {stats.line_full_frames:,} frame(s) refused so far (at most "
             f"{self.line.bound * 1000:.0f} ms of line time waits for the board)")

    # --- the clients --------------------------------------------------------------------

    def joined(self, client: _Client | _PtyClient, peer: str) -> None:
        client.stats = ClientStats(self.next_client, peer)
        self.next_client += 1
        self.clients.append(client)
        self.history.append(client.stats)
        self.joined_at[client.stats.client] = asyncio.get_running_loop().time()
        note(f"board {self.name}: client #{client.stats.client} connected ({peer})")

    def from_client(self, client: _Client | _PtyClient, contents: Sequence[bytes]) -> None:
        """The frames one read of a client brought, in order."""
        if not contents:
            return
        stats = client.stats
        if self.controller is None:
            self.controller = client
            stats.role = "controller"
            note(f"board {self.name}: client #{stats.client} ({stats.peer}) is the "
                 "controller")
        if client is self.controller:
            self.to_board(stats, contents)
            return
        for content in contents:
            if _identity_query(content):
                # A question that changes nothing on the board: passed on, its IA goes to
                # every client as every frame does (another client's link ignores an answer
                # to a nonce it did not send).
                self.to_board(stats, [content])
            else:
                self._refuse(client, self.controller.stats.client, content)

    def _refuse(self, client: _Client | _PtyClient, controller: int, content: bytes) -> None:
        stats = client.stats
        message_id = _message_id(content)
        told = self._tell_refused(client, content)
        if stats.refused_frames == 0:
            answer = "; it is answered PN 5 (another client controls the board)" \
                if told else ""
            note(f"board {self.name}: client #{stats.client} is an observer: its {message_id} "
                 f"was refused (client #{controller} controls the board){answer}; run it "
                 "with --passive, or after the controller")
        stats.refused_frames += 1
        stats.refused_by_id[message_id] += 1

    def _tell_refused(self, client: _Client | _PtyClient, content: bytes) -> bool:
        """A refused ``PS`` or ``PG`` is answered ``PN`` 5, in the form it came in (with
        the wire CRC when it carried one), so the client's link fails the request at once
        with the reason instead of resending it to no one. Whether it was answered."""
        request, with_crc = _parameter_request(content)
        if request is None:
            return False
        counter = self.answer_counters.setdefault(client.stats.client, SendCounter())
        answer = encode_message(ParamNack(request.param_id, request.channel,
                                          NackReason.NOT_CONTROLLER), counter.take())
        if with_crc:
            answer = append_crc(answer)
        return self._deliver(client, encode_frame(answer, self.framing))

    def left(self, client: _Client | _PtyClient) -> None:
        with contextlib.suppress(ValueError):
            self.clients.remove(client)
        stats = client.stats
        stats.connected = False
        since = self.joined_at.pop(stats.client, None)
        if since is not None:
            stats.connected_s = asyncio.get_running_loop().time() - since
        if client is self.controller:
            self.controller = None
            # The board is not left driven by a client that is gone: RD at once, ahead of
            # what of its frames still waits for the line.
            if not self.disable_now(None):
                self.disable_pending = True
        note(f"board {self.name}: client #{stats.client} ({stats.role}) left: "
             f"{stats.frames_to_client} frames to it, {stats.dropped_frames} dropped, "
             f"{stats.frames_to_board} to the board, {stats.refused_frames} refused"
             + (f", {stats.line_full_frames} refused for a full line"
                if stats.line_full_frames else "")
             + (f", {stats.overtaken_frames} dropped behind an RD"
                if stats.overtaken_frames else ""))

    def close(self) -> None:
        """The router stops: an RD for a controller still connected, ahead of its queue."""
        self._stop_pump()
        if self.controller is not None:
            self.controller = None
            self.disable_now(None)


def _parameter_request(content: bytes) -> tuple[ParamSet | ParamGet | None, bool]:
    """A ``PS`` or ``PG`` in ``content``, plain or with a good wire CRC (and which)."""
    message = parse_content(content)
    if isinstance(message, ParamSet | ParamGet):
        return message, False
    body = strip_crc(content)
    if body is not None:
        message = parse_content(body)
        if isinstance(message, ParamSet | ParamGet):
            return message, True
    return None, False


def _identity_query(content: bytes) -> bool:
    """An ``IQ`` (docs/protocol.md §8), plain or with a good wire CRC."""
    if isinstance(parse_content(content), IdentityQuery):
        return True
    body = strip_crc(content)
    return body is not None and isinstance(parse_content(body), IdentityQuery)


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
    Column("line_full_frames", "line full", justify="right", drop=3),
    Column("overtaken_frames", "behind RD", justify="right", drop=3),
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
    counted, a refused PS or PG answered "refused by the router" (run watchers with
    --passive). What waits for a board is at most 200 ms of line time: a controller
    writing faster has the rest refused, counted. When the controller leaves, the board
    gets RD at once, ahead of its frames still waiting (dropped, counted). A board's port
    that goes away is reopened until it is back. -v says each RE and RD a client passes.
    Ctrl-C or SIGTERM stops the router and prints each client's counts (frames delivered,
    dropped for a full buffer, passed, refused).
    """
    routes = [BoardRoute(e.name, e.url, client_buffer, baud=conn.baud, verbose=conn.verbose)
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
        route.close()
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
