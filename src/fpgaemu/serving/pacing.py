"""Pacing a board (or a robot) to a clock: the board's cycle count follows it, host bytes
enter the RX line at the cycle they arrived, never faster than the line carries them, and
TX bytes are handed out when their stop bit has ended.

A pty does not enforce a baud rate, so the pacing is ours. The serving loop sleeps until the
board's next deadline — the next event that may change something a host could see, or the
next TX byte's stop bit — or until host bytes arrive; an idle board is not woken for timer
ticks that change nothing. If the process is starved of CPU the board falls behind; it
then catches up in bounded slices, loses nothing, and the lag (how late a deadline was met)
is reported (:class:`LagReport`).

Nothing a host writes is lost: an endpoint reads no more than the line has room for
(:meth:`PacedBoard.rx_room`), and :class:`RxFlow` holds the host back while the line is
behind, as a real port's driver holds back a writer.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, TypeVar

from fpgaemu.board import Board
from fpgaemu.robot import EmulatedRobot
from fpgaemu.serving.hosts import HOST_TURN_S, HostDeadlines
from fpgaemu.serving.record import board_record
from fpgaemu.timeline import CLOCK_HZ
from fpgaemu.uartcommand import EnableCause, EnableChange

__all__ = [
    "CATCH_UP_SLICE_S",
    "LAG_THRESHOLD_S",
    "RX_BACKLOG_BYTES",
    "RX_RESUME_BYTES",
    "TX_BACKLOG_S",
    "HostHeartbeat",
    "LagReport",
    "PacedBoard",
    "PacedRobot",
    "RobotSide",
    "RxFlow",
    "earliest",
    "schedule_unplugs",
]

#: Longest slice of emulated time run in one go while catching up, so I/O stays served and
#: what the board sent in it reaches the host no later than a real board's would by this much:
#: well under the 50 periods of 1 ms after which a host takes telemetry for stopped (at 50 ms
#: a serve that fell behind handed its telemetry out in bursts a stale limit apart).
CATCH_UP_SLICE_S = 0.01
#: A deadline met later than this counts as lag.
LAG_THRESHOLD_S = 0.005
#: The longest the serving loop sleeps without a deadline (a safety net, not a tick).


#: Host bytes serve lets wait for the RX line, as the USB-UART's buffer toward the board
#: holds them (the CmodA7's FT2232H: 4 KiB per channel). While this much is waiting, serve
#: stops reading the pty or socket, so the host's write waits in its kernel buffer — as on
#: a real port — and nothing the host wrote is lost.
RX_BACKLOG_BYTES = 4096
#: Reading resumes once the backlog has drained to this (10 ms of line at 1 MBd, plenty for
#: the loop to wake): a host writing without pause keeps the line busy.
RX_RESUME_BYTES = 1024

#: TX bytes an endpoint keeps for a host that is not reading (a busy or starved process), in
#: seconds of line time; beyond it they are dropped and counted, as a USB-UART's buffer
#: overflows. The kernel's own pty buffer holds only about 40 ms at 1 MBd.
TX_BACKLOG_S = 1.0


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


@dataclass(slots=True)
class HostHeartbeat:
    """The host's heartbeat as serve saw it arrive: how many times the board's watchdog ran
    out, and the longest the host wrote nothing while the board was enabled (its ``RE``
    every 100 ms keep the watchdog's 300 ms from running out). When a watchdog lapse comes
    with a long silence here and serve itself kept up (:class:`LagReport`), the host's bytes
    reached serve late: its process or the system between them, not the board."""

    watchdog_lapses: int = 0
    longest_silence_s: float = 0.0
    _last_write: float | None = None  #: the last host write while the board was enabled

    def wrote(self, now: float, enabled: bool) -> None:
        if self._last_write is not None:
            self.longest_silence_s = max(self.longest_silence_s, now - self._last_write)
        self._last_write = now if enabled else None

    def enable_changed(self, change: EnableChange) -> None:
        if change.cause is EnableCause.WATCHDOG:
            self.watchdog_lapses += 1


@dataclass
class PacedBoard:
    """A board whose emulated time follows a monotonic clock."""

    board: Board
    clock: Callable[[], float] = time.monotonic
    lag: LagReport = field(default_factory=LagReport)
    heartbeat: HostHeartbeat = field(default_factory=HostHeartbeat)

    def __post_init__(self) -> None:
        self._origin = self.clock() - self.board.now / CLOCK_HZ
        self.board.uartcommand.on_enable_change(self.heartbeat.enable_changed)
        #: the deadlines of hosts in this process, which the board's time does not pass
        self.hosts = HostDeadlines(self.clock)
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
            self.heartbeat.wrote(self.clock() if now is None else now,
                                 self.board.uartcommand.global_enable)
            self.board.host_write(data, self._host_cycle(now))
        return len(data)

    def host_gone(self, now: float | None = None) -> int:
        """The host went away: what it wrote that the line had not begun to carry is
        discarded, as it would be with the cable. Returns how many bytes."""
        self.heartbeat.wrote(self.clock() if now is None else now, enabled=False)
        lost = self.board.host_unplugged(self._host_cycle(now))
        self.discarded_rx += lost
        return lost

    def advance(self, now: float | None = None) -> bytes:
        """Run the board up to ``now`` (in slices while catching up) and return the TX bytes
        whose stop bit ended by then."""
        self.run(now)
        return self.take_bytes()

    def take_bytes(self, whole_runs: bool = False) -> bytes:
        """The TX bytes whose stop bit has ended by the board's present, not taken before;
        with ``whole_runs``, a run (a frame) only once its last stop bit has ended."""
        return self.board.read_host_bytes(whole_runs)

    def run(self, now: float | None = None) -> None:
        """Run the board up to ``now``, in slices while catching up."""
        target = self.target_cycle(now)
        if self._due is not None and target >= self._due:
            self.lag.observe((target - self._due) / CLOCK_HZ)
            self._due = None
        target = self.hosts.allow(target, self.target_cycle)
        step_to = target
        deadline = self.board.next_deadline()
        if deadline is not None and deadline <= target:
            # Work to do on the way: in slices, so I/O is served while catching up. (Up to
            # the next deadline there are only ticks that change nothing: no slicing.)
            step_to = min(target, max(deadline, self.board.now
                                      + int(CATCH_UP_SLICE_S * CLOCK_HZ)))
        if step_to > self.board.now:
            self.board.run_until(step_to)

    def next_wake(self) -> float | None:
        """When :meth:`advance` next has something to do (monotonic seconds): the board's
        next deadline (now, if it is already past: catching up) or the end of the frame now
        on its TX pin; ``None`` when nothing is scheduled at all."""
        return self._hosts_wake(self._wake_at(self.board.next_deadline(),
                                              self.board.uartwrite.next_completion))

    def pending_cycle(self) -> int | None:
        """The earliest cycle at which the board has work to do that the host could see
        (its next deadline, the end of the frame on its TX pin)."""
        return earliest(self.board.next_deadline(), self.board.uartwrite.next_completion)

    def behind(self, now: float | None = None) -> float:
        """How far this board's emulated time trails the clock it follows (read now, or
        ``now`` if given: a reading of that clock), in seconds: 0
        while it keeps up (a board with nothing due is never behind), else the time since
        its earliest work still undone came due — a process starved as a whole, the board
        with it. An in-process host keeps its own time by this
        (:data:`FAR_END_LAG_EXTRA`): what the board has not yet had the time to do is not
        what it failed to do. Nor does it run past the earliest deadline its in-process
        host has not met yet (:class:`~fpgaemu.serving.hosts.HostDeadlines`): then it
        trails by at least the time since that came."""
        now = self.clock() if now is None else now
        pending = self.pending_cycle()
        lag = 0.0 if pending is None else max(0.0, now - self.time_of(pending))
        return max(lag, self.hosts.trailing(now))

    def _hosts_wake(self, wake: float | None) -> float | None:
        """While a host's deadline is overdue, the board waits for the host's turn."""
        if wake is not None and self.hosts.overdue() is not None:
            return max(wake, self.clock() + HOST_TURN_S)
        return wake

    def _wake_at(self, *cycles: int | None) -> float | None:
        due = min((c for c in cycles if c is not None), default=None)
        self._due = due
        # One cycle past the deadline: a float round trip must not land a cycle short.
        return None if due is None else self._origin + (due + 1) / CLOCK_HZ


def schedule_unplugs(paced: PacedBoard, unplug: Callable[[], None],
                     replug: Callable[[], None]) -> None:
    """Call ``unplug`` and ``replug`` at the board's ``unplug=`` fault windows (emulated
    time from when it started, on the clock it is paced to)."""
    faults = paced.board.peripherals.get("faults")
    loop = asyncio.get_running_loop()
    offset = loop.time() - paced.clock()  # the pacing clock onto the loop's
    for start, end in getattr(faults, "unplugs", ()):
        loop.call_at(paced.time_of(start) + offset, unplug)
        loop.call_at(paced.time_of(end) + offset, replug)


Moment = TypeVar("Moment", int, float)


def earliest(*moments: Moment | None) -> Moment | None:
    """The earliest of the cycles (or times) given, ``None`` for none."""
    return min((m for m in moments if m is not None), default=None)


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
        self.hosts = HostDeadlines(clock)  #: shared by the sides (PacedBoard.hosts)
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
        target = self.hosts.allow(target, self.target_cycle)
        # The body moves with the wheels in 1 ms steps: always sliced.
        step_to = min(target, self.robot.now + int(CATCH_UP_SLICE_S * CLOCK_HZ))
        if step_to > self.robot.now:
            self.robot.run_until(step_to)
        self._catching_up = self.robot.now < target

    def next_wake(self, read: Iterable[Board] | None = None) -> float | None:
        """:meth:`PacedBoard.next_wake` over every board of the robot (the body moves
        with them and needs no wake-up of its own): each board's next deadline, and the end
        of the frame on the TX pin of each board in ``read`` (default: every board; a board
        whose host is not reading now has nothing to hand out)."""
        held = self.hosts.overdue()
        if held is not None:
            # Waiting for a host in this process to meet its deadline: its turn first.
            return self.clock() + HOST_TURN_S
        if self.robot.now < self.target_cycle() - int(CATCH_UP_SLICE_S * CLOCK_HZ):
            return self.clock()
        boards = self.robot.boards.values()
        cycles = [c for c in (b.next_deadline() for b in boards) if c is not None]
        cycles += [c for c in (b.uartwrite.next_completion
                               for b in (boards if read is None else read)) if c is not None]
        self._due = min(cycles, default=None)
        return None if self._due is None else self._origin + (self._due + 1) / CLOCK_HZ

    def pending_cycle(self) -> int | None:
        """:meth:`PacedBoard.pending_cycle` over every board of the robot."""
        return earliest(*(c for board in self.robot.boards.values()
                          for c in (board.next_deadline(), board.uartwrite.next_completion)))

    def behind(self, now: float | None = None) -> float:
        """:meth:`PacedBoard.behind` for the robot: while it catches up in slices its body
        has work at every step (a physics body's is not free), so it trails by all the time
        since its present; otherwise by how late its boards' earliest work is."""
        now = self.clock() if now is None else now
        if self._catching_up:
            lag = max(0.0, now - self.time_of(self.robot.now))
        else:
            pending = self.pending_cycle()
            lag = 0.0 if pending is None else max(0.0, now - self.time_of(pending))
        return max(lag, self.hosts.trailing(now))

    def truth_record(self) -> dict[str, Any]:
        """The body's true state, and each board as the emulator sees it (for tests and
        tools that check what a host reports against what happened)."""
        return {**self.robot.truth().record(),
                "boards": {name: board_record(board)
                           for name, board in self.robot.boards.items()}}


class RobotSide(PacedBoard):
    """One board of a :class:`PacedRobot`, as the endpoints see a paced board."""

    def __init__(self, robot: PacedRobot, name: str) -> None:
        super().__init__(robot.robot.boards[name], robot.clock, robot.lag)
        self.robot = robot
        self.hosts = robot.hosts
        self.name = name
        self._handed_out_to = robot.robot.now  #: the robot's cycle when this side last read

    def target_cycle(self, now: float | None = None) -> int:
        return self.robot.target_cycle(now)

    def time_of(self, cycle: int) -> float:
        return self.robot.time_of(cycle)

    def run(self, now: float | None = None) -> None:
        self.robot.advance(now)

    def take_bytes(self, whole_runs: bool = False) -> bytes:
        self._handed_out_to = self.robot.robot.now
        return self.board.read_host_bytes(whole_runs)

    def next_wake(self) -> float | None:
        return self.robot.next_wake()

    def pending_cycle(self) -> int | None:
        return self.robot.pending_cycle()

    def behind(self, now: float | None = None) -> float:
        now = self.clock() if now is None else now
        lag = self.robot.behind(now)
        if self.robot.robot.now > self._handed_out_to:
            # The robot ran on for the other board: what this board sent meanwhile waits for
            # this side's turn, so its host's time stays where this side last handed out.
            lag = max(lag, now - self.time_of(self._handed_out_to))
        return lag

    def release(self) -> None:
        self.robot.release(self.name)


class RxFlow:
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

