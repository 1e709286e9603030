"""Serving emulated boards as devices: a pseudo-terminal or a TCP port per board, or an
in-process asyncio transport for ``emu://``, all paced to the wall clock.

A pty does not enforce a baud rate, so the pacing is ours: the board's cycle count follows
real time, host bytes enter ``uartread`` at the cycle they arrived (queuing at line rate
behind earlier ones, as on a wire), and TX bytes are handed out when their stop bit has
ended in emulated time. The serving loop sleeps until the board's next deadline — the next
event that may change something a host could see, or the next TX byte's stop bit — or until
host bytes arrive; an idle board is not woken for timer ticks that change nothing. If the
process is starved of CPU the board falls behind real time; it then catches up in bounded
slices, loses nothing, and the lag (how late a deadline was met) is reported.

Nothing a host writes is lost: a host that writes faster than the line carries is held
back (backpressure), as a real port's driver holds back a writer. Serve reads the pty or
socket only while fewer than :data:`RX_BACKLOG_BYTES` wait for the line, so the host's
``write`` waits in its kernel buffer and serve's memory stays bounded; ``emu://`` does the
same in asyncio terms. A host that does not read what the board sends may lose it, counted,
as a real port's receive buffer overflows.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import json
import os
import select
import selectors
import socket
import sys
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fpgaemu.board import Board
from fpgaemu.build import board_from_url
from fpgaemu.robot import EmulatedRobot, robot_from_options, robot_from_url
from fpgaemu.timeline import CLOCK_HZ
from fpgalink.protocol import PARAMETERS

PARAMETERS_BY_ID = {p.id: p for p in PARAMETERS}

__all__ = [
    "FAR_END_LAG_EXTRA",
    "MAX_TRUTH_READERS",
    "RX_BACKLOG_BYTES",
    "TRUTH_EXTRA",
    "EmulatedTransport",
    "LagReport",
    "PacedBoard",
    "PacedRobot",
    "PreciseEpollSelector",
    "PtyEndpoint",
    "RobotSide",
    "TcpEndpoint",
    "TruthEndpoint",
    "open_emulated_transport",
    "say",
    "serve_loop",
]

#: Longest slice of emulated time run in one go while catching up, so I/O stays served and
#: what the board sent in it reaches the host no later than a real board's would by this much:
#: well under the 50 periods of 1 ms after which a host takes telemetry for stopped (at 50 ms
#: a serve that fell behind handed its telemetry out in bursts a stale limit apart).
CATCH_UP_SLICE_S = 0.01
#: A deadline met later than this counts as lag.
LAG_THRESHOLD_S = 0.005
#: The longest the serving loop sleeps without a deadline (a safety net, not a tick).
MAX_SLEEP_S = 1.0


#: Host bytes serve lets wait for the RX line, as the USB-UART's buffer toward the board
#: holds them (the CmodA7's FT2232H: 4 KiB per channel). While this much is waiting, serve
#: stops reading the pty or socket, so the host's write waits in its kernel buffer — as on
#: a real port — and nothing the host wrote is lost.
RX_BACKLOG_BYTES = 4096
#: Reading resumes once the backlog has drained to this (10 ms of line at 1 MBd, plenty for
#: the loop to wake): a host writing without pause keeps the line busy.
RX_RESUME_BYTES = 1024


@dataclass(slots=True)
class LagReport:
    """How far the board fell behind the wall clock: how late its deadlines were met."""

    lag_events: int = 0
    worst_lag_s: float = 0.0
    current_lag_s: float = 0.0
    _lagging: bool = False

    def observe(self, late_s: float) -> None:
        self.current_lag_s = max(0.0, late_s)
        if self.current_lag_s > LAG_THRESHOLD_S:
            if not self._lagging:
                self.lag_events += 1
                self._lagging = True
            self.worst_lag_s = max(self.worst_lag_s, self.current_lag_s)
        else:
            self._lagging = False


@dataclass
class PacedBoard:
    """A board whose emulated time follows a monotonic clock."""

    board: Board
    clock: Callable[[], float] = time.monotonic
    lag: LagReport = field(default_factory=LagReport)

    def __post_init__(self) -> None:
        self._origin = self.clock() - self.board.now / CLOCK_HZ
        self._due: int | None = None  #: the deadline the last wake-up was for
        #: host bytes discarded because their host left before the line carried them
        self.discarded_rx = 0

    def target_cycle(self, now: float | None = None) -> int:
        now = self.clock() if now is None else now
        return int((now - self._origin) * CLOCK_HZ)

    def time_of(self, cycle: int) -> float:
        """The monotonic time at which the board reaches ``cycle``."""
        return self._origin + cycle / CLOCK_HZ

    def _host_cycle(self, now: float | None) -> int:
        # Never earlier than the board's present, even if it has fallen behind the clock.
        return max(self.board.now, self.target_cycle(now))

    def rx_backlog(self, now: float | None = None) -> int:
        """Host bytes written but not yet begun on the RX line at wall time ``now``."""
        line = self.board.uartread
        return max(0, -(-(line.line_free_at - self._host_cycle(now)) // line.cycles_per_byte))

    def rx_room(self, now: float | None = None) -> int:
        """How many more host bytes the line takes now (:data:`RX_BACKLOG_BYTES` less the
        backlog): an endpoint reads no more than this, and stops reading at 0."""
        return max(0, RX_BACKLOG_BYTES - self.rx_backlog(now))

    def rx_resume_at(self) -> float:
        """When the backlog will have drained to :data:`RX_RESUME_BYTES` (monotonic s)."""
        line = self.board.uartread
        return self.time_of(line.line_free_at - RX_RESUME_BYTES * line.cycles_per_byte + 1)

    def host_write(self, data: bytes, now: float | None = None) -> int:
        """Bytes the host wrote at wall time ``now`` enter the RX pin then (or as soon as
        the board has caught up to that moment — never earlier than its present), queued
        behind what the line has not carried yet. All of them: the endpoints bound the
        backlog by reading no more than :meth:`rx_room`. Returns ``len(data)``."""
        if data:
            self.board.host_write(data, self._host_cycle(now))
        return len(data)

    def host_gone(self, now: float | None = None) -> int:
        """The host went away: what it wrote that the line had not begun to carry is
        discarded, as it would be with the cable. Returns how many bytes."""
        lost = self.board.host_unplugged(self._host_cycle(now))
        self.discarded_rx += lost
        return lost

    def advance(self, now: float | None = None) -> bytes:
        """Run the board up to ``now`` (in slices while catching up) and return the TX bytes
        whose stop bit ended by then."""
        target = self.target_cycle(now)
        if self._due is not None and target >= self._due:
            self.lag.observe((target - self._due) / CLOCK_HZ)
            self._due = None
        step_to = target
        deadline = self.board.next_deadline()
        if deadline is not None and deadline <= target:
            # Work to do on the way: in slices, so I/O is served while catching up. (Up to
            # the next deadline there are only ticks that change nothing: no slicing.)
            step_to = min(target, max(deadline, self.board.now
                                      + int(CATCH_UP_SLICE_S * CLOCK_HZ)))
        if step_to > self.board.now:
            self.board.run_until(step_to)
        return self.board.read_host_bytes()

    def next_wake(self) -> float | None:
        """When :meth:`advance` next has something to do (monotonic seconds): the board's
        next deadline (now, if it is already past: catching up) or the end of the frame now
        on its TX pin; ``None`` when nothing is scheduled at all."""
        return self._wake_at(self.board.next_deadline(), self.board.uartwrite.next_completion)

    def pending_cycle(self) -> int | None:
        """The earliest cycle at which the board has work to do that the host could see
        (its next deadline, the end of the frame on its TX pin)."""
        return _earliest(self.board.next_deadline(), self.board.uartwrite.next_completion)

    def behind(self) -> float:
        """How far this board's emulated time trails the clock it follows, in seconds: 0
        while it keeps up (a board with nothing due is never behind), else the time since
        its earliest work still undone came due — a process starved as a whole, the board
        with it. An in-process host keeps its own time by this
        (:data:`FAR_END_LAG_EXTRA`): what the board has not yet had the time to do is not
        what it failed to do."""
        pending = self.pending_cycle()
        return 0.0 if pending is None else max(0.0, self.clock() - self.time_of(pending))

    def _wake_at(self, *cycles: int | None) -> float | None:
        due = min((c for c in cycles if c is not None), default=None)
        self._due = due
        # One cycle past the deadline: a float round trip must not land a cycle short.
        return None if due is None else self._origin + (due + 1) / CLOCK_HZ


def _schedule_unplugs(paced: PacedBoard, unplug: Callable[[], None],
                      replug: Callable[[], None]) -> None:
    """Call ``unplug`` and ``replug`` at the board's ``unplug=`` fault windows (emulated
    time from when it started, on the clock it is paced to)."""
    faults = paced.board.peripherals.get("faults")
    loop = asyncio.get_running_loop()
    offset = loop.time() - paced.clock()  # the pacing clock onto the loop's
    for start, end in getattr(faults, "unplugs", ()):
        loop.call_at(paced.time_of(start) + offset, unplug)
        loop.call_at(paced.time_of(end) + offset, replug)


def _earliest(*cycles: int | None) -> int | None:
    return min((c for c in cycles if c is not None), default=None)


#: ``transport.get_extra_info(FAR_END_LAG_EXTRA)`` on an in-process emulated board: a
#: function giving how far, in seconds, the board's time trails the host's clock
#: (:meth:`PacedBoard.behind`). fpgalink's link keeps its time that much behind, so a host
#: process starved together with its board does not take the board's unmade samples for a
#: board that stopped (the name is fpgalink's, which never imports the emulator).
FAR_END_LAG_EXTRA = "fpgalink.far_end_lag"

#: ``transport.get_extra_info(TRUTH_EXTRA)`` on an emulated robot's board: a function that
#: returns the body's true state as a JSON-ready dict (fpgalink reads it without importing
#: the emulator).
TRUTH_EXTRA = "fpgaemu.truth"


class PacedRobot:
    """An emulated robot whose boards and body follow the wall clock together: one origin,
    one lag report, every board advanced to the same cycle (:class:`RobotSide` gives each
    board the interface a :class:`PacedBoard` has, for the endpoints)."""

    def __init__(self, robot: EmulatedRobot, clock: Callable[[], float] = time.monotonic
                 ) -> None:
        self.robot = robot
        self.clock = clock
        self.lag = LagReport()
        self._origin = clock() - robot.now / CLOCK_HZ
        self._due: int | None = None
        self._catching_up = False  #: the last advance stopped short of the clock
        self._sides: dict[str, RobotSide] = {}
        self._open: set[str] = set()
        self.on_release: Callable[[], None] | None = None

    def target_cycle(self, now: float | None = None) -> int:
        now = self.clock() if now is None else now
        return int((now - self._origin) * CLOCK_HZ)

    def time_of(self, cycle: int) -> float:
        return self._origin + cycle / CLOCK_HZ

    def side(self, name: str) -> RobotSide:
        if name not in self.robot.boards:
            raise ValueError(f"the robot has no board {name!r} (boards: "
                             f"{', '.join(self.robot.boards)})")
        if name in self._open:
            raise ValueError(f"robot board {name} is already open in this process")
        side = self._sides.get(name)
        if side is None:
            side = self._sides[name] = RobotSide(self, name)
        self._open.add(name)
        return side

    def release(self, name: str) -> None:
        self._open.discard(name)
        if not self._open and self.on_release is not None:
            self.on_release()

    def advance(self, now: float | None = None) -> None:
        """Boards and body up to ``now``, in bounded slices while catching up."""
        target = self.target_cycle(now)
        if self._due is not None and target >= self._due:
            self.lag.observe((target - self._due) / CLOCK_HZ)
            self._due = None
        # The body moves with the wheels in 1 ms steps: always sliced.
        step_to = min(target, self.robot.now + int(CATCH_UP_SLICE_S * CLOCK_HZ))
        if step_to > self.robot.now:
            self.robot.run_until(step_to)
        self._catching_up = self.robot.now < target

    def next_wake(self) -> float | None:
        """:meth:`PacedBoard.next_wake` over every board of the robot (the body moves
        with them and needs no wake-up of its own)."""
        if self.robot.now < self.target_cycle() - int(CATCH_UP_SLICE_S * CLOCK_HZ):
            return self.clock()
        cycles = [c for board in self.robot.boards.values()
                  for c in (board.next_deadline(), board.uartwrite.next_completion)
                  if c is not None]
        self._due = min(cycles, default=None)
        return None if self._due is None else self._origin + (self._due + 1) / CLOCK_HZ

    def pending_cycle(self) -> int | None:
        """:meth:`PacedBoard.pending_cycle` over every board of the robot."""
        return _earliest(*(c for board in self.robot.boards.values()
                           for c in (board.next_deadline(), board.uartwrite.next_completion)))

    def behind(self) -> float:
        """:meth:`PacedBoard.behind` for the robot: while it catches up in slices its body
        has work at every step (a physics body's is not free), so it trails by all the time
        since its present; otherwise by how late its boards' earliest work is."""
        if self._catching_up:
            return max(0.0, self.clock() - self.time_of(self.robot.now))
        pending = self.pending_cycle()
        return 0.0 if pending is None else max(0.0, self.clock() - self.time_of(pending))

    def truth_record(self) -> dict[str, Any]:
        """The body's true state, and each board as the emulator sees it (for tests and
        tools that check what a host reports against what happened)."""
        return {**self.robot.truth().record(),
                "boards": {name: _board_record(board)
                           for name, board in self.robot.boards.items()}}


def _board_record(board: Board) -> dict[str, Any]:
    """A board's state for the truth stream: the last tick (as its TM stamps it), the
    speeds and encoder counts the firmware sampled then (what that TM carries), the wheels'
    references now, the PWM applied now (global_enable gates it in logic: 0 from the cycle
    enable fell), the enable, when the last RE arrived and when and why enable last fell,
    the parameters."""
    firmware: Any = board.peripherals["firmware"]
    enable_cycle = board.uartcommand.last_enable_cycle
    disable = board.uartcommand.last_disable
    return {
        "t_us": ((firmware.last_tick - board.powered_at) // 100) & 0xFFFF_FFFF,
        "speed_a": firmware.channels[1].speed, "speed_b": firmware.channels[2].speed,
        "position_a": firmware.channels[1].position,
        "position_b": firmware.channels[2].position,
        # deg/s (N·m under current control): what the firmware's loops are asked now
        "reference_a": firmware.channels[1].reference,
        "reference_b": firmware.channels[2].reference,
        "pwm_a": board.channels[1].pwm.applied_duty,
        "pwm_b": board.channels[2].pwm.applied_duty,
        "enabled": board.global_enable,
        "now_s": board.now / CLOCK_HZ,
        "last_re_s": None if enable_cycle is None else enable_cycle / CLOCK_HZ,
        "disabled_s": None if disable is None else disable[0] / CLOCK_HZ,
        "disabled_by": None if disable is None else disable[1].value,
        "params": {PARAMETERS_BY_ID[pid].full_name(ch): value
                   for (pid, ch), value in firmware.values.items()},
    }


class RobotSide(PacedBoard):
    """One board of a :class:`PacedRobot`, as the endpoints see a paced board."""

    def __init__(self, robot: PacedRobot, name: str) -> None:
        super().__init__(robot.robot.boards[name], robot.clock, robot.lag)
        self.robot = robot
        self.name = name
        self._handed_out_to = robot.robot.now  #: the robot's cycle when this side last read

    def target_cycle(self, now: float | None = None) -> int:
        return self.robot.target_cycle(now)

    def time_of(self, cycle: int) -> float:
        return self.robot.time_of(cycle)

    def advance(self, now: float | None = None) -> bytes:
        self.robot.advance(now)
        self._handed_out_to = self.robot.robot.now
        return self.board.read_host_bytes()

    def next_wake(self) -> float | None:
        return self.robot.next_wake()

    def pending_cycle(self) -> int | None:
        return self.robot.pending_cycle()

    def behind(self) -> float:
        lag = self.robot.behind()
        if self.robot.robot.now > self._handed_out_to:
            # The robot ran on for the other board: what this board sent meanwhile waits for
            # this side's turn, so its host's time stays where this side last handed out.
            lag = max(lag, self.clock() - self.time_of(self._handed_out_to))
        return lag

    def release(self) -> None:
        self.robot.release(self.name)


class _Pacer:
    """Runs ``tick()`` (advance the board, hand out its bytes) whenever the board has a
    deadline, and when :meth:`poke` says host bytes arrived — never on a fixed beat."""

    def __init__(self, tick: Callable[[], None], next_wake: Callable[[], float | None]
                 ) -> None:
        self._tick = tick
        self._next_wake = next_wake
        self._timer: asyncio.TimerHandle | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self.wakeups = 0

    def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._wake()

    def poke(self) -> None:
        """Something changed (host bytes arrived): the next deadline may be sooner."""
        if self._loop is not None:
            self._arm()

    def _wake(self) -> None:
        self._timer = None
        self.wakeups += 1
        self._tick()
        self._arm()

    def _arm(self) -> None:
        loop = self._loop
        assert loop is not None
        at = self._next_wake()
        now = loop.time()
        at = now + MAX_SLEEP_S if at is None else min(at, now + MAX_SLEEP_S)
        if self._timer is not None:
            if self._timer.when() <= at:
                return
            self._timer.cancel()
        self._timer = loop.call_at(at, self._wake)

    async def stop(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._loop = None


# --- the event loop ---------------------------------------------------------------------------


class PreciseEpollSelector(selectors.EpollSelector):
    """epoll — any number of descriptors, at any number — with timers met to the
    microsecond. ``epoll_wait`` takes whole milliseconds and rounds a wait up, which would put
    every reply up to a millisecond late; so a wait with a timeout is spent in ``select()``
    on the epoll descriptor itself (readable when any watched descriptor is ready, and
    ``select``'s timeout is in microseconds), then epoll is asked, without waiting, which.
    (When the epoll descriptor itself is above ``select``'s limit of 1024 the wait is
    epoll's own, to the millisecond.)"""

    def __init__(self) -> None:
        super().__init__()
        self._precise = self.fileno() < FD_SETSIZE

    def select(self, timeout: float | None = None
               ) -> list[tuple[selectors.SelectorKey, int]]:
        if self._precise and timeout is not None and timeout > 0:
            with contextlib.suppress(InterruptedError):
                select.select([self.fileno()], [], [], timeout)
            timeout = 0
        return super().select(timeout)


#: ``select()``'s limit: descriptors at or above it cannot be watched with it.
FD_SETSIZE = 1024


def serve_loop() -> asyncio.AbstractEventLoop:
    """The event loop ``fpgaemu serve`` runs on: the platform's default selector (epoll on
    Linux, as :class:`PreciseEpollSelector`), so no number of connections is too many for
    it."""
    default: type[selectors.BaseSelector] = selectors.DefaultSelector
    if default is selectors.EpollSelector:
        return asyncio.SelectorEventLoop(PreciseEpollSelector())
    return asyncio.SelectorEventLoop(default())


def say(text: str, *, once: str | None = None) -> None:
    """One line ``fpgaemu: TEXT`` on stderr; with ``once``, only the first time that key is
    said in this process."""
    if once is not None:
        if once in _SAID:
            return
        _SAID.add(once)
    print(f"fpgaemu: {text}", file=sys.stderr, flush=True)


_SAID: set[str] = set()


# --- backpressure on the host's bytes ---------------------------------------------------------


class _RxFlow:
    """Backpressure on what the host writes: an endpoint takes no more than the line has
    room for (:meth:`PacedBoard.rx_room`), stops reading while more than
    :data:`RX_RESUME_BYTES` wait (``pause``), and reads again once the backlog has drained
    to that (``resume``, at the wake-up :meth:`next_wake` adds to the board's own) — so a
    fast host is read about 3 KiB at a time, every 30 ms at 1 MBd, not a few bytes per
    wake-up."""

    def __init__(self, paced: PacedBoard, pause: Callable[[], None],
                 resume: Callable[[], None]) -> None:
        self.paced = paced
        self._pause = pause
        self._resume = resume
        self.paused = False
        self.pauses = 0  #: times the host was held back

    def took(self) -> None:
        """Host bytes went in: hold the host back while the line is behind."""
        if not self.paused and self.paced.rx_backlog() > RX_RESUME_BYTES:
            self.paused = True
            self.pauses += 1
            self._pause()

    def check(self) -> None:
        """At a wake-up: let the host write again once the backlog has drained."""
        if self.paused and self.paced.rx_backlog() <= RX_RESUME_BYTES:
            self.paused = False
            self._resume()

    def reset(self) -> None:
        """The host went away: the next one starts unpaused."""
        self.paused = False

    def next_wake(self) -> float | None:
        wake = self.paced.next_wake()
        if self.paused:
            resume = self.paced.rx_resume_at()
            wake = resume if wake is None else min(wake, resume)
        return wake


# --- listening ---------------------------------------------------------------------------------

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
        _turn_away(connection, message)  # closed: its descriptor is the spare again
        cls.keep()
        return True


def _turn_away(connection: socket.socket, message: bytes) -> None:
    """Tell a connection why it is not served (if its buffer takes it now) and close it."""
    with connection:
        connection.setblocking(False)
        with contextlib.suppress(OSError):
            connection.send(message)


def _usable_url(address: str, port: int) -> str:
    """``socket://…`` a client can connect to: a wildcard address becomes its family's
    loopback."""
    address = {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(address, address)
    host = f"[{address.split('%')[0]}]" if ":" in address else address
    return f"socket://{host}:{port}"


def _requested_url(host: str, port: int) -> str:
    """The address asked for, for a message (``*`` for every interface)."""
    shown = f"[{host}]" if ":" in host else host or "*"
    return f"socket://{shown}:{port}"


class _Listener:
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
                self.urls.append(_usable_url(address, bound))
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


# --- pty --------------------------------------------------------------------------------------


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

#: TX bytes a pty keeps for a host that is not reading (a busy or starved process), in
#: seconds of line time; beyond it the oldest are dropped and counted, as a USB-UART's
#: buffer overflows. The kernel's own pty buffer holds only about 40 ms at 1 MBd.
TX_BACKLOG_S = 1.0


class PtyEndpoint:
    """One board behind a pseudo-terminal. We keep the slave side open ourselves, so a host
    that closes and reopens the path finds the same board still running. Host bytes are read
    only as fast as the line carries them: while :data:`RX_BACKLOG_BYTES` wait, the pty is
    not read and the host's ``write`` waits in the kernel's tty buffer."""

    def __init__(self, paced: PacedBoard) -> None:
        self.paced = paced
        self._open_pty()
        self.flow = _RxFlow(paced, self._pause, self._resume)
        self.pacer = _Pacer(self._tick, self.flow.next_wake)
        self._pending_out = bytearray()
        self._writing = False
        self._backlog = int(TX_BACKLOG_S * paced.board.config.baud / 10)
        #: TX bytes lost because nobody read the pty for longer than the backlog holds
        self.dropped_tx = 0
        #: a stable symlink to the pty (``--link``), pointed at the new pty on a replug
        self.link: Path | None = None
        self.unplugged = False
        self.unplugs = 0
        #: TX bytes the board sent while unplugged (gone, as on a pulled cable)
        self.unplugged_tx = 0

    def _open_pty(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)

    def start(self) -> None:
        asyncio.get_running_loop().add_reader(self._master, self._readable)
        self.pacer.start()
        _schedule_unplugs(self.paced, self._unplug, self._replug)

    def remove_own_link(self) -> None:
        """Remove the ``--link`` if it points at the pty served now: another serve or router
        may have taken the name since. An unplugged pty's link went with it, and its freed
        number may be another's now."""
        if self.link is None or self.unplugged:
            return
        with contextlib.suppress(OSError):
            if os.readlink(self.link) == self.path:
                self.link.unlink()

    def _unplug(self) -> None:
        """The USB-UART is pulled out: the pty goes (the host's next read fails), what the
        host wrote that the line had not begun is gone, and the board runs on unheard. The
        ``--link`` goes with it, as udev's /dev/serial/by-id link goes with a pulled
        USB-UART: the freed pty's number may be given to another program meanwhile, and a
        host reopening the link must find nothing, not that program's pty."""
        if self.unplugged:
            return
        self.remove_own_link()
        self.unplugged = True
        self.unplugs += 1
        loop = asyncio.get_running_loop()
        with contextlib.suppress(Exception):
            loop.remove_reader(self._master)
        if self._writing:
            with contextlib.suppress(Exception):
                loop.remove_writer(self._master)
            self._writing = False
        self.unplugged_tx += len(self._pending_out)
        self._pending_out.clear()
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        self.paced.host_gone()
        self.flow.reset()
        say(f"unplugged {self.path}")

    def _replug(self) -> None:
        """Plugged in again: a new pty (a new name, as a USB-UART may come back as another
        ttyUSB), the ``--link`` symlink made again, pointing at it."""
        if not self.unplugged:
            return
        self._open_pty()
        self.unplugged = False
        shown = self.path
        if self.link is not None:
            shown = f"{self.link} -> {self.path}"
            try:
                if self.link.is_symlink() and not self.link.exists():
                    self.link.unlink()  # a stale link (its pty gone): ours to replace
                self.link.symlink_to(self.path)
            except FileExistsError:
                # Taken while unplugged (another serve or router): theirs, left alone.
                shown = f"{self.path} (--link {self.link} is now another's, left alone)"
            except OSError as exc:
                shown = f"{self.path} (--link {self.link}: {exc.strerror or exc})"
        asyncio.get_running_loop().add_reader(self._master, self._readable)
        say(f"plugged in again: {shown}")

    def _pause(self) -> None:
        if not self.unplugged:
            asyncio.get_running_loop().remove_reader(self._master)

    def _resume(self) -> None:
        if not self.unplugged:
            asyncio.get_running_loop().add_reader(self._master, self._readable)

    def _readable(self) -> None:
        room = self.paced.rx_room()
        if room <= 0:
            self.flow.took()
            return
        try:
            data = os.read(self._master, room)
        except BlockingIOError:
            return
        except OSError:
            return  # no reader on the slave side right now; the board keeps running
        self.paced.host_write(data)
        self.flow.took()
        self.pacer.poke()

    def _tick(self) -> None:
        out = self.paced.advance()
        self.flow.check()
        if self.unplugged:
            self.unplugged_tx += len(out)
            return
        if out:
            self._pending_out += out
        self._flush()

    def _flush(self) -> None:
        if self.unplugged:
            return
        if self._pending_out:
            try:
                written = os.write(self._master, self._pending_out)
                del self._pending_out[:written]
            except OSError:
                pass  # the pty is full (nobody reading just now): keep the bytes for later
            excess = len(self._pending_out) - self._backlog
            if excess > 0:
                # Nobody read for longer than the backlog: the oldest bytes are gone, counted
                # rather than blocking the board.
                del self._pending_out[:excess]
                self.dropped_tx += excess
        # Bytes left over go out when the pty has room, not on the next deadline.
        loop = asyncio.get_running_loop()
        if self._pending_out and not self._writing:
            loop.add_writer(self._master, self._flush)
            self._writing = True
        elif not self._pending_out and self._writing:
            loop.remove_writer(self._master)
            self._writing = False

    async def close(self) -> None:
        await self.pacer.stop()
        if self.unplugged:
            return
        if self._writing:
            with contextlib.suppress(Exception):
                asyncio.get_running_loop().remove_writer(self._master)
        with contextlib.suppress(Exception):
            asyncio.get_running_loop().remove_reader(self._master)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)


# --- TCP --------------------------------------------------------------------------------------


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
        self.endpoint._connected(self)

    def get_buffer(self, sizehint: int) -> memoryview:
        # At least one byte: a read is only asked for while the line had room.
        room = max(1, min(len(self._buffer), self.endpoint.paced.rx_room()))
        return memoryview(self._buffer)[:room]

    def buffer_updated(self, nbytes: int) -> None:
        self.sent_anything = True
        self.endpoint._host_bytes(bytes(self._buffer[:nbytes]))

    def eof_received(self) -> bool:
        return False  # the host is done: close

    def connection_lost(self, exc: Exception | None) -> None:
        self.endpoint._disconnected(self)


class TcpEndpoint:
    """One board on a TCP port, one host at a time, as a serial port has one owner. A second
    host is told ``busy: another host is connected`` and disconnected (after
    :data:`BUSY_GRACE_S`, in case the first has just left). What a departed host wrote that
    the line had not begun to carry is discarded. Host bytes are read only as fast as the
    line carries them (the host's writes wait in its socket meanwhile); TX bytes a host does
    not read pile up to the same backlog a pty keeps, then the newest are dropped and
    counted. A host that sends nothing for ``idle_timeout`` seconds after connecting is
    told so and disconnected."""

    def __init__(self, paced: PacedBoard, host: str, port: int, *,
                 idle_timeout: float = IDLE_TIMEOUT_S) -> None:
        self.paced = paced
        self.host = host
        self.idle_timeout = idle_timeout
        self.listener = _Listener(host, port, self._accepted, NO_DESCRIPTOR_MESSAGE,
                                  rcvbuf=HOST_RCVBUF_BYTES)
        self.flow = _RxFlow(paced, self._pause, self._resume)
        self.pacer = _Pacer(self._tick, self.flow.next_wake)
        self._backlog = int(TX_BACKLOG_S * paced.board.config.baud / 10)
        self._connection: _HostConnection | None = None
        self._busy = False  #: a host is being connected or is connected
        self._free: asyncio.Event | None = None
        self._closing = False
        self._tasks: set[asyncio.Task[None]] = set()
        self._idle: asyncio.TimerHandle | None = None
        self.unplugged = False
        self.unplugs = 0
        self._port_when_unplugged = port
        self.connections = 0
        self.turned_away = 0  #: hosts told "busy"
        self.idle_closed = 0  #: hosts disconnected for sending nothing
        #: TX bytes lost because the host did not read them for longer than the backlog holds
        self.dropped_tx = 0

    @property
    def port(self) -> int:
        return self.listener.port

    @property
    def urls(self) -> list[str]:
        """A ``socket://`` URL per listening socket, each usable by a client."""
        return self.listener.urls or [_requested_url(self.host, self.port)]

    @property
    def url(self) -> str:
        return self.urls[0]

    async def start(self) -> None:
        self._free = asyncio.Event()
        self._free.set()
        self.listener.open()
        self.pacer.start()
        _schedule_unplugs(self.paced, self._unplug, self._replug)

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

    def _spawn(self, coro: Any) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _accepted(self, connection: socket.socket) -> None:
        if self._closing or self.unplugged:
            connection.close()
        elif not self._busy:
            self._take(connection)
        else:
            self._spawn(self._when_free(connection))

    async def _when_free(self, connection: socket.socket) -> None:
        # Most often the host being served has just left and serve has not seen it yet.
        assert self._free is not None
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._free.wait(), BUSY_GRACE_S)
        if self._busy or self._closing:
            self.turned_away += 1
            _turn_away(connection, BUSY_MESSAGE)
        else:
            self._take(connection)

    def _take(self, connection: socket.socket) -> None:
        assert self._free is not None
        self._busy = True
        self._free.clear()
        self._spawn(self._attach(connection))

    async def _attach(self, connection: socket.socket) -> None:
        try:
            await asyncio.get_running_loop().connect_accepted_socket(
                lambda: _HostConnection(self), connection)
        except OSError:
            connection.close()
            self._release()

    def _connected(self, connection: _HostConnection) -> None:
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

    def _host_bytes(self, data: bytes) -> None:
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

    def _disconnected(self, connection: _HostConnection) -> None:
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

    def _tick(self) -> None:
        out = self.paced.advance()
        self.flow.check()
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
        self.listener.close()
        if self._idle is not None:
            self._idle.cancel()
        self.unplug()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)


# --- the robot's truth -------------------------------------------------------------------------

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
        self.endpoint._joined(self)

    def connection_lost(self, exc: Exception | None) -> None:
        self.endpoint._left(self)


class TruthEndpoint:
    """The emulated body's true state for up to :data:`MAX_TRUTH_READERS` readers on a TCP
    port: one JSON object per line every :data:`TRUTH_PERIOD_S` (``t x y theta v omega
    distance surface``; metres, radians, seconds of emulated time; ``boards``: each board's
    state, see :func:`_board_record`; ``host_time``: the host's epoch time the boards were
    advanced to, so board time maps onto the host clock). Read-only. Each line is built once
    and the same bytes are written to every reader, so the boards' timing does not depend on
    how many watch; a reader more than :data:`TRUTH_BACKLOG_BYTES` behind is aborted."""

    def __init__(self, robot: PacedRobot, host: str, port: int) -> None:
        self.robot = robot
        self.host = host
        self.listener = _Listener(host, port, self._accepted, _error_line(
            "busy: serve has no file descriptor left"), backlog=64)
        self._readers: set[_TruthReader] = set()
        self._attaching: set[socket.socket] = set()  #: accepted, not yet readers
        self._timer: asyncio.Handle | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self.publications = 0  #: lines built (each sent to every reader)
        self.turned_away = 0  #: readers refused over the cap
        self.aborted = 0  #: readers let go for not reading

    @property
    def port(self) -> int:
        return self.listener.port

    @property
    def urls(self) -> list[str]:
        return self.listener.urls or [_requested_url(self.host, self.port)]

    @property
    def url(self) -> str:
        return self.urls[0]

    @property
    def readers(self) -> int:
        return len(self._readers)

    async def start(self) -> None:
        self.listener.open()

    def _accepted(self, connection: socket.socket) -> None:
        if len(self._readers) + len(self._attaching) >= MAX_TRUTH_READERS:
            self.turned_away += 1
            _turn_away(connection, _error_line(
                f"busy: {MAX_TRUTH_READERS} truth readers are connected, the most serve "
                "takes"))
            return
        with contextlib.suppress(OSError):
            connection.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, TRUTH_SNDBUF_BYTES)
        self._attaching.add(connection)
        task = asyncio.ensure_future(self._attach(connection))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _attach(self, connection: socket.socket) -> None:
        try:
            await asyncio.get_running_loop().connect_accepted_socket(
                lambda: _TruthReader(self, connection), connection)
        except OSError:
            connection.close()
        finally:
            self._attaching.discard(connection)

    def _joined(self, reader: _TruthReader) -> None:
        # A reader from now on, counted once: no longer among those being attached.
        self._attaching.discard(reader.connection)
        self._readers.add(reader)
        if self._timer is None:  # the first reader: publish now, then every period
            self._timer = asyncio.get_running_loop().call_soon(self._publish)

    def _left(self, reader: _TruthReader) -> None:
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
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)


def _error_line(text: str) -> bytes:
    """A JSON line a truth reader parses as an error rather than a pose."""
    return (json.dumps({"error": text}) + "\n").encode()


# --- emu:// in-process ------------------------------------------------------------------------

#: asyncio's own defaults for a transport's write buffer: the protocol is asked to pause
#: writing above the high mark and to resume at the low one.
WRITE_BUFFER_HIGH = 64 * 1024


class EmulatedTransport(asyncio.Transport):
    """An asyncio transport whose far end is a board in this process. What the host writes
    is never dropped: it waits in the transport's buffer and goes onto the RX line as the
    line makes room, as a serial transport's buffer drains into its port; the protocol's
    ``pause_writing()``/``resume_writing()`` are called at the buffer's limits, as asyncio's
    own transports do (:meth:`set_write_buffer_limits`, :meth:`get_write_buffer_size`)."""

    def __init__(self, paced: PacedBoard, protocol: asyncio.Protocol) -> None:
        super().__init__()
        self.paced = paced
        self._protocol = protocol
        self._closing = False
        self._buffer = bytearray()  #: written by the host, not yet on the RX line
        self._high = WRITE_BUFFER_HIGH
        self._low = WRITE_BUFFER_HIGH // 4
        self._protocol_paused = False
        self.pacer = _Pacer(self._tick, self._next_wake)
        self.pacer.start()

    def _next_wake(self) -> float | None:
        wake = self.paced.next_wake()
        if self._buffer:
            feed = self.paced.rx_resume_at()
            wake = feed if wake is None else min(wake, feed)
        return wake

    def _tick(self) -> None:
        out = self.paced.advance()
        self._feed()
        if out and not self._closing:
            self._protocol.data_received(out)

    def _feed(self, everything: bool = False) -> None:
        """Move buffered bytes onto the RX line as far as it has room (all of them when the
        transport closes: they were written before it did)."""
        if self._buffer:
            # The host in this process lives on the board's time (FAR_END_LAG_EXTRA): what
            # it writes enters the line at the board's present, even when the board trails
            # the wall clock, so heartbeats reach the board as far apart as they were sent.
            now = self.paced.clock() - self.paced.behind()
            room = len(self._buffer) if everything else self.paced.rx_room(now)
            if room > 0:
                self.paced.host_write(bytes(self._buffer[:room]), now)
                del self._buffer[:room]
        self._flow()

    def _flow(self) -> None:
        size = len(self._buffer)
        if not self._protocol_paused and size > self._high:
            self._protocol_paused = True
            self._protocol.pause_writing()
        elif self._protocol_paused and size <= self._low:
            self._protocol_paused = False
            self._protocol.resume_writing()

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if not self._closing and data:
            self._buffer += data
            self._feed()
            self.pacer.poke()

    def get_write_buffer_size(self) -> int:
        return len(self._buffer)

    def get_write_buffer_limits(self) -> tuple[int, int]:
        return self._low, self._high

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None
                                ) -> None:
        if high is None:
            high = WRITE_BUFFER_HIGH if low is None else 4 * low
        if low is None:
            low = high // 4
        if not high >= low >= 0:
            raise ValueError(f"high ({high!r}) must be >= low ({low!r}) must be >= 0")
        self._high, self._low = high, low
        self._flow()

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        if self._closing:
            return
        self._feed(everything=True)
        self._closing = True
        loop = asyncio.get_running_loop()
        self._stopping = loop.create_task(self.pacer.stop())
        loop.call_soon(self._protocol.connection_lost, None)
        if isinstance(self.paced, RobotSide):
            self.paced.release()

    def abort(self) -> None:
        self._buffer.clear()
        self.close()

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        if name == "board":
            return self.paced.board
        if name == FAR_END_LAG_EXTRA:
            return self.paced.behind
        if name == TRUTH_EXTRA and isinstance(self.paced, RobotSide):
            return self.paced.robot.truth_record
        return default


async def open_emulated_transport(
    url: str, baud: int, protocol_factory: Callable[[], asyncio.Protocol]
) -> tuple[asyncio.BaseTransport, asyncio.Protocol]:
    """The ``emu://`` opener ``fpgalink`` finds through the ``fpgalink.transports`` entry
    point: a board built from the URL's options, paced to the wall clock in this process.
    ``emu://robot/L`` and ``emu://robot/R`` (same options) are the two boards of one
    emulated robot. ``ValueError`` for an option the emulator does not understand."""
    if "unplug=" in url:
        raise ValueError("unplug= is a fault of fpgaemu serve's pty or TCP link: a board in "
                         "this process has no port to pull out")
    robot = robot_from_url(url)
    if robot is not None:
        key, side_name, options = robot
        paced: PacedBoard = _shared_robot(key, options, baud).side(side_name)
    else:
        paced = PacedBoard(board_from_url(url, baud), clock=asyncio.get_running_loop().time)
    protocol = protocol_factory()
    transport = EmulatedTransport(paced, protocol)
    protocol.connection_made(transport)
    return transport, protocol


#: In-process robots, by their URL options (without the board), shared by the links to
#: their boards; dropped when the last of those closes.
_ROBOTS: dict[tuple[str, int], PacedRobot] = {}


def _shared_robot(key: str, options: dict[str, list[str]], baud: int) -> PacedRobot:
    paced = _ROBOTS.get((key, baud))
    if paced is None:
        # Paced by the loop's own clock: the wall clock on asyncio's loops, emulated time on
        # a campaign's (fpgalink.aio.virtual_time_loop), where the board runs as fast as it goes.
        paced = _ROBOTS[(key, baud)] = PacedRobot(robot_from_options(options, baud),
                                                  asyncio.get_running_loop().time)

        def forget() -> None:
            _ROBOTS.pop((key, baud), None)

        paced.on_release = forget
    return paced
