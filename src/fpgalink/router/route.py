"""One board's port shared among its clients (:class:`BoardRoute`): the board's frames to
every client, the controller's toward the board at the line's pace, the port lost and
found again. Who the controller is, is :mod:`.arbitration`'s; what waits for the line,
:mod:`.linequeue`'s."""

from __future__ import annotations

import asyncio
import contextlib
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from fpgalink.aio.transport import open_transport
from fpgalink.errors import PortError
from fpgalink.protocol.framing import DEFAULT_FRAMING, FrameDecoder, Framing, encode_frame
from fpgalink.router.arbitration import Arbitration, identity_query
from fpgalink.router.linequeue import LineQueue
from fpgalink.router.stats import Client, ClientStats, message_id

__all__ = ["DISABLE", "FULL_NOTE_EVERY_S", "REOPEN_BACKOFF", "BoardRoute", "say_on_stderr"]

DISABLE = encode_frame(b"RD", DEFAULT_FRAMING)
#: First and longest wait between tries to reopen a board's port that went away, s: a
#: USB-UART plugged back in is found within a quarter second, and a port that stays away
#: costs four failed opens a second.
REOPEN_BACKOFF = (0.05, 0.25)
#: A controller whose frames are refused for a full line is told on stderr at most this
#: often (with the count so far), s.
FULL_NOTE_EVERY_S = 2.0


def say_on_stderr(text: str) -> None:
    """A route's notes, by default: one line each on stderr."""
    print(text, file=sys.stderr, flush=True)


class _BoardPort(asyncio.Protocol):
    """The board's port as the event loop sees it: what it reads goes to the route."""

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
    """One board's port shared among its clients. Every count is exact; what it notices
    (a client joined, refused, left; the port lost, back) is said through ``say``."""

    name: str
    url: str
    client_buffer: int
    framing: Framing = DEFAULT_FRAMING
    #: the line's bit rate: what waits for the board is paced and bounded in its time
    baud: int = 1_000_000
    #: -v: each enable and disable a client passes to the board is said, as it happens
    #: (who enabled the motor, and whether it disabled it before it left)
    verbose: int = 0
    #: where its notes go, one line each (the CLI's ``note``: ``fpgalink-cli: …``)
    say: Callable[[str], None] = say_on_stderr
    board: asyncio.BaseTransport | None = None
    #: resolved when the board's port goes away (set anew each time it is opened)
    lost: asyncio.Future[Exception | None] | None = None
    decoder: FrameDecoder = field(default_factory=lambda: FrameDecoder(DEFAULT_FRAMING))
    clients: list[Client] = field(default_factory=list)
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
    #: the controller's frames waiting for the line: (its stats, message ID, wire bytes)
    line: LineQueue[tuple[ClientStats, str, bytes]] = field(init=False)
    arbitration: Arbitration[Client] = field(default_factory=Arbitration, init=False)
    #: when each connected client joined (loop time), by client number
    joined_at: dict[int, float] = field(default_factory=dict)
    _pump_timer: asyncio.TimerHandle | None = field(default=None, init=False, repr=False)
    _full_said_at: float = field(default=-math.inf, init=False, repr=False)

    def __post_init__(self) -> None:
        self.line = LineQueue(self.baud)

    @property
    def controller(self) -> Client | None:
        """The client whose frames go to the board (``None``: nobody's, yet)."""
        return self.arbitration.controller

    # --- the board ----------------------------------------------------------------------

    async def open(self) -> None:
        """Open the board's port (:class:`~fpgalink.errors.PortError` when it cannot be)."""
        holder: list[_BoardPort] = []

        def factory() -> _BoardPort:
            holder.append(_BoardPort(self))
            return holder[-1]

        self.board, _ = await open_transport(self.url, self.baud, factory)
        self.lost = holder[0].lost

    async def keep_open(self, reconnect: bool) -> None:
        """Reopen the board's port each time it goes away, with backoff, while the clients
        stay connected. Returns only when it went away for good (``reconnect`` off)."""
        while True:
            assert self.lost is not None
            self.port_lost(await self.lost)
            if not reconnect:
                return
            delay, ceiling = REOPEN_BACKOFF
            tries = 0
            while True:
                await asyncio.sleep(delay)
                tries += 1
                try:
                    await self.open()
                except PortError:
                    delay = min(2 * delay, ceiling)
                    continue
                self.port_back(tries)
                break

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
        self.say(f"board {self.name}: port {self.url} lost ({cause})")

    def port_back(self, tries: int) -> None:
        away = time.monotonic() - (self.lost_since or time.monotonic())
        self.lost_since = None
        self.reconnects += 1
        self.say(f"board {self.name}: port {self.url} back after {away:.1f} s "
                 f"({tries} {'try' if tries == 1 else 'tries'}); its clients stayed "
                 "connected")
        # The controller that left while the port was gone may have left the board enabled
        # (an outage shorter than its 300 ms watchdog): RD goes first, whoever controls it
        # now. A new controller's frames sent during the outage were not delivered; its
        # next RE enables the board again.
        if self.disable_pending and self.disable_now(None):
            self.disable_pending = False
            self.say(f"board {self.name}: RD sent for the controller that left while the "
                     "port was gone")

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

    def _deliver(self, client: Client, wire: bytes) -> bool:
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

    # --- the controller's frames, at the line's pace ------------------------------------

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
            if not line.push((stats, message_id(content), wire), len(wire), now):
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
            self.say(f"board {self.name}: RD sent ahead of {len(overtaken):,} queued "
                     f"frame(s) of client #{overtaken[0][0].client} (dropped, counted); "
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
            for stats, message_id_, _ in taken:
                self._passed(stats, message_id_)
        wake = self.line.wake_at()
        if wake is not None and self._pump_timer is None:
            self._pump_timer = loop.call_at(wake, self._pump)

    def _stop_pump(self) -> None:
        if self._pump_timer is not None:
            self._pump_timer.cancel()
            self._pump_timer = None

    def _passed(self, stats: ClientStats, message_id_: str) -> None:
        stats.frames_to_board += 1
        stats.to_board_by_id[message_id_] += 1
        if self.verbose and message_id_ in ("RE", "RD"):
            self.say(f"board {self.name}: client #{stats.client} sent {message_id_}")

    def _say_full(self, stats: ClientStats, now: float) -> None:
        if now - self._full_said_at < FULL_NOTE_EVERY_S:
            return
        self._full_said_at = now
        self.say(f"board {self.name}: client #{stats.client} writes faster than the line "
                 f"carries: {stats.line_full_frames:,} frame(s) refused so far (at most "
                 f"{self.line.bound * 1000:.0f} ms of line time waits for the board)")

    # --- the clients --------------------------------------------------------------------

    def joined(self, client: Client, peer: str) -> None:
        client.stats = ClientStats(self.next_client, peer)
        self.next_client += 1
        self.clients.append(client)
        self.history.append(client.stats)
        self.joined_at[client.stats.client] = asyncio.get_running_loop().time()
        self.say(f"board {self.name}: client #{client.stats.client} connected ({peer})")

    def from_client(self, client: Client, contents: Sequence[bytes]) -> None:
        """The frames one read of a client brought, in order."""
        if not contents:
            return
        stats = client.stats
        if self.arbitration.take(client):
            self.say(f"board {self.name}: client #{stats.client} ({stats.peer}) is the "
                     "controller")
        if self.arbitration.controls(client):
            self.to_board(stats, contents)
            return
        for content in contents:
            if identity_query(content):
                self.to_board(stats, [content])
            else:
                self._refuse(client, content)

    def _refuse(self, client: Client, content: bytes) -> None:
        """An observer's frame, not passed on: counted, answered when the protocol has an
        answer for it, said the first time."""
        stats = client.stats
        answer = self.arbitration.refusal(client, content)
        told = answer is not None and self._deliver(client, encode_frame(answer,
                                                                         self.framing))
        if stats.refused_frames == 0:
            controller = self.controller
            assert controller is not None
            said = "; it is answered PN 5 (another client controls the board)" \
                if told else ""
            self.say(f"board {self.name}: client #{stats.client} is an observer: its "
                     f"{message_id(content)} was refused (client #{controller.stats.client} "
                     f"controls the board){said}; run it with --passive, or after the "
                     "controller")
        stats.refused_frames += 1
        stats.refused_by_id[message_id(content)] += 1

    def left(self, client: Client) -> None:
        with contextlib.suppress(ValueError):
            self.clients.remove(client)
        stats = client.stats
        stats.connected = False
        since = self.joined_at.pop(stats.client, None)
        if since is not None:
            stats.connected_s = asyncio.get_running_loop().time() - since
        # The board is not left driven by a client that is gone: RD at once, ahead of what
        # of its frames still waits for the line.
        if self.arbitration.release(client) and not self.disable_now(None):
            self.disable_pending = True
        self.say(f"board {self.name}: client #{stats.client} ({stats.role}) left: "
                 f"{stats.frames_to_client} frames to it, {stats.dropped_frames} dropped, "
                 f"{stats.frames_to_board} to the board, {stats.refused_frames} refused"
                 + (f", {stats.line_full_frames} refused for a full line"
                    if stats.line_full_frames else "")
                 + (f", {stats.overtaken_frames} dropped behind an RD"
                    if stats.overtaken_frames else ""))

    def close(self) -> None:
        """The router stops: an RD for a controller still connected, ahead of its queue."""
        self._stop_pump()
        if self.arbitration.release():
            self.disable_now(None)
