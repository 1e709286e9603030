"""The robot's boards' faults and their recovery, over asyncio: the one place the robot reads
its links' events (:meth:`BoardRecovery.on_link_event`). Each becomes a supervision input
(the robot stops at once, in the callback that noticed), a :class:`BoardNotice` for the
robot's readers (the ROS node's log and diagnostics, a campaign's recording), and for a
board that restarted, its recovery: once its link has set again what it holds, what
odometry and joint states use is read back, and once its link has asked who it is again
(a re-flash changes it: docs/protocol.md §8) the board is ready again — never while it
answers with another protocol declaration than this host's, unless the robot allows it.
What a restarted board leaves unanswered (silent meanwhile, or answering late) is asked
again once it is heard (docs/robot.md, Faults)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from dataclasses import dataclass

from fpgalink.aio.link import Link
from fpgalink.errors import BoardLost, FpgalinkError, RequestTimeout
from fpgalink.events import (
    BoardBack,
    BoardFound,
    BoardIdentified,
    BoardRestarted,
    BoardResynced,
    BoardSilent,
    Closed,
    PortLost,
    PortRestored,
    StatusEvent,
    TelemetryResumed,
    TelemetryStale,
    WatchdogLapsed,
    WireCrcMismatch,
)
from fpgalink.protocol.robot import RobotDescription
from fpgalink.robot.supervision import Action, Fault, Supervisor

__all__ = ["BoardNotice", "BoardRecovery"]

#: A restarted board's read-back it did not answer is asked again this often (s) while it
#: is heard: a late answer (a loaded machine) or a silence must not leave it blocked.
READ_BACK_RETRY_S = 0.1

#: Status events that are faults: a reader logs them as errors (and says so at once).
_FAULTS = (BoardSilent, PortLost, BoardRestarted, WatchdogLapsed, TelemetryStale,
           WireCrcMismatch)


@dataclass(frozen=True, slots=True)
class BoardNotice:
    """Something a board's link noticed: ``kind`` as the link names it (the status event's
    :attr:`~fpgalink.events.StatusEvent.name`: ``board_lost``, ``board_restarted``,
    ``closed``…), ``detail`` its :meth:`~fpgalink.events.StatusEvent.describe`, ``fault``
    when it is one (a resync that failed included), ``at`` on the loop's clock."""

    board: str
    at: float
    kind: str
    detail: str
    fault: bool

    def describe(self) -> str:
        return f"board {self.board}: {self.kind.replace('_', ' ')}" + (
            f" ({self.detail})" if self.detail else "")


ReadBack = Callable[[str, int, str, float], None]


class BoardRecovery:
    """The robot's boards' faults (see the module docstring). The robot gives it what it
    acts through: ``carry_out`` (supervision's actions), ``now`` (the loop's clock),
    ``guarded`` (a block whose exception stops the robot for good), ``restarted`` (a board
    restarted: forget its counts and clocks), ``read_back`` (board, channel, parameter,
    value read back) and ``notify`` (each :class:`BoardNotice`); ``allow_mismatch``: a
    board that restarts into another protocol declaration may be ready again."""

    def __init__(self, description: RobotDescription, supervisor: Supervisor, *,
                 carry_out: Callable[[list[Action]], None], now: Callable[[], float],
                 guarded: Callable[[str], contextlib.AbstractContextManager[None]],
                 restarted: Callable[[str], None], read_back: ReadBack,
                 notify: Callable[[BoardNotice], None], allow_mismatch: bool = False) -> None:
        self.description = description
        self.supervisor = supervisor
        self._carry_out, self._now, self._guarded = carry_out, now, guarded
        self._restarted_hook, self._read_back_hook, self._notify = restarted, read_back, notify
        #: boards restarted and not yet reconfigured, and boards whose telemetry stopped
        self.reconfiguring: set[str] = set()
        self.stale: dict[str, str] = {}
        #: boards heard again after a silence, not yet known whether they restarted
        self.checking: set[str] = set()
        #: restarted boards not yet asked who they are now, and those that answered with
        #: another protocol declaration (why, as said)
        self.identifying: set[str] = set()
        self.mismatched: dict[str, str] = {}
        self.allow_mismatch = allow_mismatch
        #: restarts seen per board: a read-back still trying belongs to the newest only
        self.restarts: dict[str, int] = {}
        self._tasks: set[asyncio.Task[None]] = set()

    @property
    def reading_back(self) -> int:
        """Restarted boards' read-backs under way (a finished one is not kept)."""
        return len(self._tasks)

    async def close(self) -> None:
        """Cancel the read-backs under way."""
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()

    def on_link_event(self, name: str, link: Link, event: StatusEvent, react: bool = True
                      ) -> None:
        """Board ``name``'s link noticed ``event`` (synchronously, as it happened): the
        robot reacts (``react``: once started, until closed), then its readers hear of it."""
        with self._guarded(f"board {name}'s {event.name} event"):
            if react:
                self._link_event(name, link, event)
            detail = event.describe()
            self._notify(BoardNotice(
                name, event.at, event.name, detail, isinstance(event, _FAULTS) or (
                    isinstance(event, BoardResynced) and not event.ok) or (
                    isinstance(event, BoardIdentified) and event.mismatch is not None
                    and not self.allow_mismatch)))

    def _link_event(self, name: str, link: Link, event: StatusEvent) -> None:
        # The robot reacts in the callback that noticed: its events carry that moment.
        now, detail = event.at, event.describe()
        if isinstance(event, BoardSilent | PortLost | Closed):
            what = event.name.replace("_", " ")
            detail = f"{what} ({detail})" if detail else what
            self._carry_out(self.supervisor.board_alive(name, False, now, detail))
        elif isinstance(event, BoardRestarted):
            self._restarted(name, detail, now)
        elif isinstance(event, BoardResynced):
            # The restart this resync answers is the one counted now: another restart may
            # be counted before the task first runs.
            task = asyncio.ensure_future(self._reconfigured(
                name, link, event, self.restarts.get(name, 0)))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
        elif isinstance(event, WatchdogLapsed):
            why = (f"watchdog: host silent {event.host_silent_for * 1000:.0f} ms"
                   if event.host_silent_for is not None else f"watchdog: {event.detail}")
            self._carry_out(self.supervisor.board_fault(name, Fault.WATCHDOG_LAPSED, now, why))
        elif isinstance(event, TelemetryStale):
            self.stale[name] = detail
            self._carry_out(self.supervisor.board_fault(name, Fault.TELEMETRY_STALE, now,
                                                        detail))
        elif isinstance(event, TelemetryResumed):
            if self.stale.pop(name, None) is not None:
                self._board_recovered(name, "telemetry flowing again", now)
        elif isinstance(event, BoardBack):
            self.checking.discard(name)
            self._board_recovered(name, detail, now)
        elif isinstance(event, BoardIdentified):
            self._identified(name, event, now)
        elif isinstance(event, BoardFound | PortRestored) and link.board_alive:
            self.supervisor.board_alive(name, True, now)
            if link.connection.verifying:
                # Heard again after a silence: whether it restarted meanwhile is being
                # asked; not ready until the answer comes.
                self.checking.add(name)
                self.supervisor.blocked[name] = "heard again: checking whether it restarted"

    def _restarted(self, name: str, detail: str, now: float) -> None:
        """The board restarted: stop, forget its counts (a reset is not motion), and wait
        for its link to set again what it holds."""
        self.checking.discard(name)
        self.reconfiguring.add(name)
        self.identifying.add(name)  # asked at start, so its link asks again
        self.restarts[name] = self.restarts.get(name, 0) + 1
        self.stale.pop(name, None)
        self._restarted_hook(name)
        self._carry_out(self.supervisor.board_fault(
            name, Fault.RESTARTED, now,
            f"restarted: reconfiguring ({detail.removeprefix('restarted: ')})"))

    async def _reconfigured(self, name: str, link: Link, resynced: BoardResynced,
                            restart: int) -> None:
        """The link set again what it holds: read back what odometry and joint states use,
        then the board is ready (or says why not). What the board left unanswered (silent
        meanwhile, or answering late) is asked again once it is heard: a resync that failed
        only for that, and the read-back."""
        with self._guarded(f"reconfiguring board {name}"):
            failure = None if resynced.ok else resynced.describe()
            if failure is not None and all(isinstance(error, RequestTimeout | BoardLost)
                                           for _, error in resynced.failed):
                self._carry_out(self.supervisor.board_fault(
                    name, Fault.RESTARTED, self._now(),
                    f"restarted: {failure} (set again when it answers)"))
                await _heard(link, READ_BACK_RETRY_S)
                if self.restarts.get(name, 0) == restart and name in self.reconfiguring:
                    link.resync()  # its BOARD_RESYNCED comes back here
                return
            if failure is None:
                try:
                    if not await self._read_back(name, link, restart):
                        return  # restarted again: that restart's resync reads back
                except (FpgalinkError, ValueError) as exc:
                    failure = f"reading back after the restart: {exc}"
            now = self._now()
            if failure is not None:
                self._carry_out(self.supervisor.board_fault(
                    name, Fault.RESTARTED, now, f"restarted: {failure}"))
                return
            if name in self.reconfiguring and self.restarts.get(name, 0) == restart:
                self.reconfiguring.discard(name)
                self._board_recovered(name, resynced.describe(), now)

    async def _read_back(self, name: str, link: Link, restart: int) -> bool:
        """Read back each wheel's resolution and torque coefficient, each asked again until
        the board answers it (False: the board restarted again meanwhile)."""
        for wheel in self.description.wheels:
            if wheel.board == name:
                for param in ("IncSenzRes", "TorqueCoef"):
                    value = await self._read_one(name, link, param, wheel.channel, restart)
                    if value is None:
                        return False
                    self._read_back_hook(name, wheel.channel, param, value)
        return True

    async def _read_one(self, name: str, link: Link, param: str, channel: int, restart: int
                        ) -> int | float | None:
        said = False
        while True:
            try:
                return await link.get_param(param, channel)
            except (BoardLost, RequestTimeout) as exc:
                if not said:
                    said = True
                    self._carry_out(self.supervisor.board_fault(
                        name, Fault.RESTARTED, self._now(),
                        f"restarted: reading back after the restart: {exc} "
                        f"(asked again when it answers)"))
                await _heard(link, READ_BACK_RETRY_S)
                if self.restarts.get(name, 0) != restart:
                    return None

    def _identified(self, name: str, event: BoardIdentified, now: float) -> None:
        """The restarted board said who it is now: another protocol declaration keeps it not
        ready (the robot stopped when it restarted), unless the robot allows it."""
        self.identifying.discard(name)
        mismatch = event.mismatch
        if mismatch is not None and not self.allow_mismatch:
            why = f"restarted into another protocol: {mismatch}"
            self.mismatched[name] = why
            self._carry_out(self.supervisor.board_fault(name, Fault.RESTARTED, now, why))
            return
        if self.mismatched.pop(name, None) is not None or name in self.supervisor.blocked:
            self._board_recovered(name, event.describe(), now)

    def _board_recovered(self, name: str, detail: str, now: float) -> None:
        """One of the board's faults cleared: ready again once none is left."""
        if name in self.mismatched:
            self.supervisor.blocked[name] = self.mismatched[name]
        elif name in self.reconfiguring:
            self.supervisor.blocked[name] = "restarted: reconfiguring"
        elif name in self.identifying:
            self.supervisor.blocked[name] = "restarted: asking who it is now"
        elif name in self.checking:
            self.supervisor.blocked[name] = "heard again: checking whether it restarted"
        elif name in self.stale:
            self.supervisor.blocked[name] = self.stale[name]
        else:
            self._carry_out(self.supervisor.board_ready(name, now, detail))


async def _heard(link: Link, pause: float) -> None:
    """Once the board answers and is not being checked for a restart: at once if it does
    (a request asked again at once is confirmed by a late answer to the last), else looked
    at every ``pause``."""
    while not link.board_alive or link.connection.verifying:
        await asyncio.sleep(pause)
