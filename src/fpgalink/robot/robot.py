"""The robot over asyncio: one :class:`~fpgalink.aio.Link` per board, with the sans-I/O
parts (:mod:`.drive`, :mod:`.odometry`, :mod:`.supervision`, :mod:`.goto`) fed from the
links' telemetry and events and the loop's clock.

Faults stop it and say why (``docs/robot.md``, Faults): a board that restarts is
reconfigured by its link (every parameter set through it, set again) and re-anchored here
(its encoder counts and clock start again, which is not motion), and is not ready until
that is confirmed; a board whose telemetry stops is not ready until it comes again; a
board whose watchdog lapsed stops the robot; any exception in the robot's own tasks and
callbacks stops it for good (it is not ready any more).

    async with Robot.open(seed_robot(), {"L": "emu://robot/L", "R": "emu://robot/R"}) as robot:
        async with robot.enabled():          # the deadman, renewed while the block runs
            await robot.go_to(1.0, 0.5)
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import functools
import math
from collections.abc import AsyncIterator, Callable, Mapping
from typing import Any

from fpgalink.aio.link import Link, Subscription, open_link
from fpgalink.errors import BoardLost, FpgalinkError, RequestTimeout
from fpgalink.events import (
    BoardBack,
    BoardFound,
    BoardRestarted,
    BoardResynced,
    BoardSilent,
    Closed,
    Event,
    PortLost,
    PortRestored,
    RequestDone,
    StatusEvent,
    TelemetryResumed,
    TelemetryStale,
    WatchdogLapsed,
)
from fpgalink.protocol import Telemetry
from fpgalink.protocol.robot import Pose, RobotDescription, SkidSteer
from fpgalink.robot.drive import WheelCommand, wheel_command
from fpgalink.robot.goto import GoTo, GoToCommand, GoToSettings
from fpgalink.robot.health import Status, WireUse, board_status, supervision_status
from fpgalink.robot.joints import JointStates, joint_states
from fpgalink.robot.odometry import Odometry, OdometryState
from fpgalink.robot.supervision import (
    DEADMAN_S,
    Action,
    Fault,
    NotReady,
    State,
    SupervisionEvent,
    Supervisor,
)

__all__ = ["TRUTH_EXTRA", "GoalTimeout", "Robot", "RobotError", "RobotStopped"]

#: What an emulated robot's transport offers for its true pose (see fpgaemu.serve).
TRUTH_EXTRA = "fpgaemu.truth"
#: How often :meth:`Robot.enabled` renews the deadman (well inside the 0.5 s).
RENEW_S = 0.1
#: Running time a caller gets to renew when the deadman's deadline passed while this loop
#: was not running (a blocked or starved process): one and a half renewal periods.
DEADMAN_GRACE_S = 1.5 * RENEW_S
#: Below these the robot counts as at rest (m/s, rad/s).
SETTLED_SPEED = 0.005
SETTLED_TURN = math.radians(0.5)
#: How long :meth:`Robot.start` waits for every board to be heard.
START_TIMEOUT_S = 5.0
#: A request a board that is heard leaves unanswered after its tries (8 × 50 ms) is asked
#: again at once this many more times (Link.unanswered_rounds): on a loaded machine an
#: answer comes later than the tries, and a robot must not give up at start for it.
UNANSWERED_ROUNDS = 4
#: How long :meth:`Robot.start` waits for a board found streaming to confirm it stopped:
#: its echo comes after the telemetry waiting in the port (serve keeps 1 s of line time, a
#: host reading at a quarter of the line drains that in 4 s).
QUIET_TIMEOUT_S = 10.0
#: A restarted board's read-back it did not answer is asked again this often (s) while it
#: is heard: a late answer (a loaded machine) or a silence must not leave it blocked.
_READ_BACK_RETRY_S = 0.1


class RobotError(FpgalinkError):
    """The robot cannot do what was asked (not started, a board missing, bad settings)."""


class RobotStopped(RobotError):
    """Supervision stopped the robot (``event`` says why), or it was not enabled."""

    def __init__(self, message: str, event: SupervisionEvent | None = None) -> None:
        super().__init__(message)
        self.event = event


class GoalTimeout(RobotError):
    """``go_to`` did not arrive in time; the robot was stopped."""


class Robot:
    """A skid-steered robot whose boards are reached through ``links`` (board name → link,
    as the description names them). The robot owns the links: it opens and closes them."""

    def __init__(self, description: RobotDescription, links: Mapping[str, Link], *,
                 deadman_s: float = DEADMAN_S, control_period: float = 0.02,
                 goto_settings: GoToSettings | None = None) -> None:
        missing = sorted(set(description.boards) - set(links))
        extra = sorted(set(links) - set(description.boards))
        if missing or extra:
            raise RobotError(f"the robot's boards are {', '.join(description.boards)}; "
                             f"links given for {', '.join(sorted(links)) or 'none'}")
        if not (math.isfinite(control_period) and 0 < control_period <= 1):
            raise ValueError(f"control_period must be in (0, 1] s, got {control_period!r}")
        self.description = description
        self.links = dict(links)
        self.control_period = control_period
        self.goto_settings = goto_settings or GoToSettings(
            max_speed=description.max_linear_speed,
            max_turn_rate=description.max_angular_speed_rad)
        self.kinematics = description.kinematics()
        self.odometry = Odometry(description, self.kinematics)
        self.supervisor = Supervisor(description.boards, deadman_s)
        self._deadman_deferred = False  #: a late deadman timer had its one turn of grace
        self.command: WheelCommand | None = None
        #: encoder pulses per turn and TorqueCoef (N·m/A) per (board, channel), read from
        #: the boards at start and followed through every confirmed change
        self.resolution: dict[tuple[str, int], int] = {}
        self.torque_coef: dict[tuple[str, int], float] = {}
        #: each board's latest telemetry sample
        self.latest: dict[str, Telemetry] = {}
        self._wire = {name: WireUse(link.connection.baud) for name, link in self.links.items()}
        self._tasks: list[asyncio.Task[None]] = []
        self._removers: list[Callable[[], None]] = []
        self._subs: set[Subscription[SupervisionEvent]] = set()
        self._timer: asyncio.TimerHandle | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._streaming_before: dict[str, int | float] = {}
        self._started = False
        self._stopped_event = asyncio.Event()
        #: boards restarted and not yet reconfigured, and boards whose telemetry stopped
        self._reconfiguring: set[str] = set()
        self._stale: dict[str, str] = {}
        #: boards heard again after a silence, not yet known whether they restarted
        self._checking: set[str] = set()
        #: restarts seen per board: a read-back still trying belongs to the newest only
        self._restarts: dict[str, int] = {}
        #: encoder counts each wheel had before its board's restarts (joint angles go on)
        self._count_offset: dict[tuple[str, int], int] = {}
        #: the exception that stopped the robot for good, if one did
        self.failure: BaseException | None = None

    @classmethod
    def open(cls, description: RobotDescription, ports: Mapping[str, str], *,
             baud: int = 1_000_000, stale_periods: int = 50, **options: Any) -> Robot:
        """A robot over links to ``ports`` (board name → URL): ``async with Robot.open(…)``.
        ``stale_periods``: timer periods without a board's telemetry that stop the robot
        (:class:`~fpgalink.Connection`); ``options`` go to the robot (deadman_s,
        control_period, goto_settings)."""
        links = {name: open_link(url, baud, name=name, stale_periods=stale_periods,
                                 unanswered_rounds=UNANSWERED_ROUNDS)
                 for name, url in ports.items()}
        return cls(description, links, **options)

    # --- lifecycle ------------------------------------------------------------------------

    async def start(self) -> Robot:
        """Open the links, wait for every board, load the description's parameters, read
        each wheel's encoder resolution back from its board, and turn telemetry on."""
        self._loop = asyncio.get_running_loop()
        try:
            await asyncio.gather(*(link.open() for link in self.links.values()))
            await self._wait_for_boards()
            # Every board found streaming is quieted before any is set up, all at once: one
            # set up first would leave the others' telemetry piling up in their ports.
            found = await asyncio.gather(*(self._quiet(name, link)
                                           for name, link in self.links.items()),
                                         return_exceptions=True)
            for name, outcome in zip(self.links, found, strict=True):
                if isinstance(outcome, BaseException):
                    raise outcome
                self._streaming_before[name] = outcome
            for name, link in self.links.items():
                await self._configure(name, link)
        except BaseException:
            await self._close_links()
            raise
        for name, link in self.links.items():
            self.supervisor.board_alive(name, link.board_alive, self._now())
            self._tasks.append(asyncio.ensure_future(self._follow_telemetry(name, link)))
            # Synchronously: the other boards get RD in the very callback that notices.
            self._removers.append(link.on_event(functools.partial(self._on_link_event, name,
                                                                  link)))
            self._removers.append(link.add_listener(functools.partial(self._on_confirmed,
                                                                      name)))
        self._started = True
        return self

    async def _wait_for_boards(self) -> None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + START_TIMEOUT_S
        while not all(link.board_alive for link in self.links.values()):
            if loop.time() > deadline:
                silent = [n for n, lk in self.links.items() if not lk.board_alive]
                raise RobotError(f"board {', '.join(silent)} not answering after "
                                 f"{START_TIMEOUT_S:g} s")
            await asyncio.sleep(0.01)

    async def _configure(self, name: str, link: Link) -> None:
        settings = self.description.settings_for(name)
        for param, channel, value in settings:
            try:
                await link.set_param(param.id, value, channel or None)
            except FpgalinkError as exc:
                raise RobotError(f"board {name}: loading {param.full_name(channel)} = "
                                 f"{value}: {exc}") from exc
        for wheel in self.description.wheels:
            if wheel.board != name:
                continue
            pulses = int(await link.get_param("IncSenzRes", wheel.channel))
            try:
                self._set_resolution(name, wheel.channel, pulses)
            except ValueError as exc:
                raise RobotError(f"board {name}: {exc}") from None
            self.torque_coef[(name, wheel.channel)] = float(
                await link.get_param("TorqueCoef", wheel.channel))
        # The link then knows the period its telemetry must keep (TelemetryStale).
        await link.get_param("TsTimerPeriod")
        await link.set_param("GetDataPeriodical", 1)

    async def _quiet(self, name: str, link: Link) -> int | float:
        """A board found streaming is turned quiet before it is set up; returns whether it
        streamed (``GetDataPeriodical``, set again at close).

        A host slower than the stream (a loaded machine, a board left sending a TM every
        1 ms by a host before) finds every answer behind the telemetry waiting in its port,
        later than a request's patience (a ROS node gave up at start: "get TorqueCoefB: no
        answer after 8 tries"). The board takes the ``0`` at once, whatever the host is
        behind on; its echo comes once what waits is read, so it is asked again for as
        long as the board is heard, up to :data:`QUIET_TIMEOUT_S` (and the request then
        under way, its tries). A board found sending telemetry counts as streaming: a
        start that fails after this leaves it quiet."""
        if not link.stats.telemetry_received:
            return await link.get_param("GetDataPeriodical")
        loop = asyncio.get_running_loop()
        deadline = loop.time() + QUIET_TIMEOUT_S
        while True:
            try:
                await link.set_param("GetDataPeriodical", 0)
                return 1
            except (RequestTimeout, BoardLost) as exc:
                if isinstance(exc, BoardLost) or loop.time() > deadline \
                        or not link.board_alive:
                    raise RobotError(f"board {name} not answering: turning its telemetry "
                                     f"off to set it up: {exc}") from exc

    async def close(self) -> None:
        """Disable every board, restore their telemetry setting, close the links."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self.supervisor.state is State.ENABLED:
            self._carry_out(self.supervisor.request_disable(self._now()))
        for remove in self._removers:
            remove()
        self._removers.clear()
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()
        for name, link in self.links.items():
            before = self._streaming_before.get(name)
            if before is not None and before != 1 and link.board_alive:
                with contextlib.suppress(FpgalinkError):
                    await link.set_param("GetDataPeriodical", before)
        await self._close_links()
        for sub in list(self._subs):
            sub.finish()
        self._subs.clear()

    async def _close_links(self) -> None:
        await asyncio.gather(*(link.close() for link in self.links.values()),
                             return_exceptions=True)

    async def __aenter__(self) -> Robot:
        return await self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # --- supervision ----------------------------------------------------------------------

    def enable(self) -> None:
        """Enable the robot, or renew the enable: it must be renewed at least every
        ``deadman_s`` (0.5 s) or every board is disabled. :class:`RobotStopped` (from
        :class:`~fpgalink.robot.supervision.NotReady`) when a board is not answering."""
        self._ensure_started()
        try:
            actions = self.supervisor.request_enable(self._now())
        except NotReady as exc:
            self._carry_out(exc.actions)
            raise RobotStopped(str(exc), self.supervisor.last_stop) from None
        self._carry_out(actions)

    def disable(self) -> None:
        """Disable every board now (``RD``)."""
        self._ensure_started()
        self._carry_out(self.supervisor.request_disable(self._now()))

    @contextlib.asynccontextmanager
    async def enabled(self, renew_every: float = RENEW_S) -> AsyncIterator[Robot]:
        """Enabled while the block runs: the deadman is renewed every ``renew_every`` s (so
        a stalled loop still lets it lapse), and the robot is stopped and disabled on the
        way out, however the block ends."""
        self.enable()

        async def renew() -> None:
            while self.supervisor.state is State.ENABLED:
                await asyncio.sleep(renew_every)
                with contextlib.suppress(RobotStopped):
                    if self.supervisor.state is State.ENABLED:
                        self.enable()

        task = asyncio.ensure_future(renew())
        try:
            yield self
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
            if self.supervisor.state is State.ENABLED:
                with contextlib.suppress(FpgalinkError):
                    self.stop()
                self.disable()

    @property
    def state(self) -> State:
        return self.supervisor.state

    @property
    def last_stop(self) -> SupervisionEvent | None:
        return self.supervisor.last_stop

    def events(self, maxsize: int = 64) -> Subscription[SupervisionEvent]:
        """Supervision events (enabled, stopped and why) as an async iterator."""
        sub: Subscription[SupervisionEvent] = Subscription(maxsize, self._subs.discard)
        self._subs.add(sub)
        return sub

    def _carry_out(self, actions: list[Action]) -> None:
        for action in actions:
            for link in self.links.values():
                with contextlib.suppress(FpgalinkError):
                    if action is Action.ENABLE_ALL:
                        # Zero first. This project's board clears its references when
                        # enable falls (SPEC §4); the seed's firmware gated only the PWM
                        # output (its §3.2) and kept its references in memory, so such a
                        # board would drive off with the last ones when enabled again.
                        link.set_references(0.0, 0.0)
                        link.enable()
                    elif action is Action.DISABLE_ALL:
                        link.disable()
                        link.set_references(0.0, 0.0)
        if any(a is Action.DISABLE_ALL for a in actions):
            self.command = None
        for event in self.supervisor.events():
            if event.state is State.DISABLED:
                self._stopped_event.set()
            for sub in self._subs:
                sub.put(event)
        self._arm_timer()

    def _arm_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        deadline = self.supervisor.get_timer()
        if deadline is not None and self._loop is not None:
            self._timer = self._loop.call_at(deadline, self._on_timer)

    def _on_timer(self) -> None:
        self._timer = None
        deadline = self.supervisor.get_timer()
        late = deadline is not None and self._now() - deadline > RENEW_S
        if late and not self._deadman_deferred and self._loop is not None:
            # This loop was not running when the deadline passed (the process blocked or was
            # starved): the deadman measures the caller's running time without a renewal,
            # and the caller had none (its renewal is queued behind this callback, or its
            # renewing task had not even started). It gets one renewal period of running
            # time, then the judgement: a caller that really stopped renewing is still
            # stopped, that much later; a stalled host's boards are stopped by their own
            # watchdog meanwhile, and its link says so (WATCHDOG_LAPSED).
            self._deadman_deferred = True
            self._timer = self._loop.call_later(DEADMAN_GRACE_S, self._on_timer)
            return
        self._deadman_deferred = False
        with self._guarded("the deadman timer"):
            self._carry_out(self.supervisor.handle_timer(self._now()))

    @contextlib.contextmanager
    def _guarded(self, what: str) -> Any:
        """Run a callback or task body; an exception in it stops the robot for good (RD to
        every board, the reason said) instead of killing it silently."""
        try:
            yield
        except Exception as exc:  # any: a dead task must not leave the robot driving
            self._task_failed(what, exc)

    def _task_failed(self, what: str, exc: BaseException) -> None:
        if self.failure is None:
            self.failure = exc
        detail = f"{what}: {type(exc).__name__}: {exc}"
        self.command = None
        for link in self.links.values():  # first, before anything else can fail
            with contextlib.suppress(Exception):
                link.disable()
        with contextlib.suppress(Exception):
            self._carry_out(self.supervisor.task_failed(self._now(), detail))

    def _on_link_event(self, name: str, link: Link, event: StatusEvent) -> None:
        with self._guarded(f"board {name}'s {event.name} event"):
            self._link_event(name, link, event)

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
                name, link, event, self._restarts.get(name, 0)))
            self._tasks.append(task)
            task.add_done_callback(self._forget_task)
        elif isinstance(event, WatchdogLapsed):
            why = (f"watchdog: host silent {event.host_silent_for * 1000:.0f} ms"
                   if event.host_silent_for is not None else f"watchdog: {event.detail}")
            self._carry_out(self.supervisor.board_fault(name, Fault.WATCHDOG_LAPSED, now, why))
        elif isinstance(event, TelemetryStale):
            self._stale[name] = detail
            self._carry_out(self.supervisor.board_fault(name, Fault.TELEMETRY_STALE, now,
                                                        detail))
        elif isinstance(event, TelemetryResumed):
            if self._stale.pop(name, None) is not None:
                self._board_recovered(name, "telemetry flowing again", now)
        elif isinstance(event, BoardBack):
            self._checking.discard(name)
            self._board_recovered(name, detail, now)
        elif isinstance(event, BoardFound | PortRestored) and link.board_alive:
            self.supervisor.board_alive(name, True, now)
            if link.connection.verifying:
                # Heard again after a silence: whether it restarted meanwhile is being
                # asked; not ready until the answer comes.
                self._checking.add(name)
                self.supervisor.blocked[name] = "heard again: checking whether it restarted"

    def _restarted(self, name: str, detail: str, now: float) -> None:
        """The board restarted: stop, forget its counts (a reset is not motion), and wait
        for its link to set again what it holds."""
        self._checking.discard(name)
        self._reconfiguring.add(name)
        self._restarts[name] = self._restarts.get(name, 0) + 1
        self._stale.pop(name, None)
        latest = self.latest.pop(name, None)
        if latest is not None:
            for wheel in self.description.wheels:
                if wheel.board == name:
                    key = (name, wheel.channel)
                    data = latest.a if wheel.channel == 1 else latest.b
                    self._count_offset[key] = self._count_offset.get(key, 0) + data.position
        self.odometry.restart(name)
        self._carry_out(self.supervisor.board_fault(
            name, Fault.RESTARTED, now, f"restarted: reconfiguring ({detail})"))

    def _forget_task(self, task: asyncio.Task[None]) -> None:
        """A finished reconfiguring task: not kept (a board left unanswered makes one per
        resync for as long as it is heard and does not answer)."""
        if task in self._tasks:
            self._tasks.remove(task)

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
                await self._heard(link, _READ_BACK_RETRY_S)
                if self._restarts.get(name, 0) == restart and name in self._reconfiguring:
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
            if name in self._reconfiguring and self._restarts.get(name, 0) == restart:
                self._reconfiguring.discard(name)
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
                    if param == "IncSenzRes":
                        self._set_resolution(name, wheel.channel, int(value))
                    else:
                        self.torque_coef[(name, wheel.channel)] = float(value)
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
                await self._heard(link, _READ_BACK_RETRY_S)
                if self._restarts.get(name, 0) != restart:
                    return None

    @staticmethod
    async def _heard(link: Link, pause: float) -> None:
        """Once the board answers and is not being checked for a restart: at once if it
        does (a request asked again at once is confirmed by a late answer to the last),
        else looked at every ``pause``."""
        while not link.board_alive or link.connection.verifying:
            await asyncio.sleep(pause)

    def _board_recovered(self, name: str, detail: str, now: float) -> None:
        """One of the board's faults cleared: ready again once none is left."""
        if name in self._reconfiguring:
            self.supervisor.blocked[name] = "restarted: reconfiguring"
        elif name in self._checking:
            self.supervisor.blocked[name] = "heard again: checking whether it restarted"
        elif name in self._stale:
            self.supervisor.blocked[name] = self._stale[name]
        else:
            self._carry_out(self.supervisor.board_ready(name, now, detail))

    async def _follow_telemetry(self, name: str, link: Link) -> None:
        with self._guarded(f"board {name}'s telemetry (odometry)"):
            async for sample in link.telemetry(maxsize=4096):
                self._on_telemetry(name, sample)

    def _on_telemetry(self, name: str, sample: Telemetry) -> None:
        self.latest[name] = sample
        self.odometry.update(name, sample)

    def _set_resolution(self, board: str, channel: int, pulses: int) -> None:
        self.odometry.set_resolution(board, channel, pulses)
        self.resolution[(board, channel)] = pulses

    def _on_confirmed(self, board: str, event: Event) -> None:
        """A parameter set through this robot's links changed a wheel's encoder resolution
        or torque coefficient: odometry and joint states follow the board."""
        with self._guarded(f"board {board}'s confirmations"):
            self._confirmed(board, event)

    def _confirmed(self, board: str, event: Event) -> None:
        if not isinstance(event, RequestDone) or (board, event.channel) not in self.resolution:
            return
        if event.param.name == "IncSenzRes":
            with contextlib.suppress(ValueError):  # 0 pulses: odometry keeps the last
                self._set_resolution(board, event.channel, int(event.value))
        elif event.param.name == "TorqueCoef":
            self.torque_coef[(board, event.channel)] = float(event.value)

    def set_kinematics(self, *, wheel_radius: float | None = None, track: float | None = None,
                       chi: float | None = None, left_radius_multiplier: float | None = None,
                       right_radius_multiplier: float | None = None) -> SkidSteer:
        """Drive and compute odometry with another wheel radius (m), track (m, between the
        left and right wheels' centres), skid-steer factor χ (≥ 1; it differs per
        surface) or a side's radius multiplier from now on; the others kept. The pose so
        far stays. ``ValueError`` for a value that is not finite and positive (χ: ≥ 1),
        and nothing changes."""
        model = self.kinematics
        radius = model.wheel_radius if wheel_radius is None else wheel_radius
        new_track = model.track if track is None else track
        new_chi = model.chi if chi is None else chi
        left = model.left_radius_multiplier if left_radius_multiplier is None \
            else left_radius_multiplier
        right = model.right_radius_multiplier if right_radius_multiplier is None \
            else right_radius_multiplier
        for name, value, low in (("wheel_radius", radius, 0.0), ("track", new_track, 0.0),
                                 ("chi", new_chi, 1.0), ("left_radius_multiplier", left, 0.0),
                                 ("right_radius_multiplier", right, 0.0)):
            if not (math.isfinite(value) and (value > low if low == 0.0 else value >= low)):
                raise ValueError(f"{name} must be a finite number "
                                 f"{'> 0' if low == 0.0 else '≥ 1'}, got {value!r}")
        self.kinematics = SkidSteer(radius, new_track, new_chi, left, right)
        self.description = dataclasses.replace(self.description, wheel_radius=radius)
        self.odometry.set_kinematics(self.description, self.kinematics)
        return self.kinematics

    # --- driving --------------------------------------------------------------------------

    def drive(self, v: float, omega: float) -> WheelCommand:
        """Drive at body speed ``v`` (m/s) and yaw rate ``omega`` (rad/s, counter-clockwise
        positive): every board gets its ``RV`` now, in this call. Limits scale the command
        keeping its curvature; non-finite values raise and nothing is sent;
        :class:`RobotStopped` unless enabled."""
        self._ensure_started()
        command = wheel_command(self.description, v, omega, self.kinematics)
        if self.supervisor.state is not State.ENABLED:
            stop = self.supervisor.last_stop
            raise RobotStopped("the robot is not enabled" + (
                f" ({stop.describe()})" if stop else ""), stop)
        for board, (ref_a, ref_b) in command.references.items():
            self.links[board].set_references(ref_a, ref_b)
        self.command = command
        return command

    def stop(self) -> None:
        """Zero references to every board (still enabled)."""
        for link in self.links.values():
            with contextlib.suppress(FpgalinkError):
                link.set_references(0.0, 0.0)
        self.command = None

    async def go_to(self, x: float, y: float, theta: float | None = None, *,
                    timeout: float = 60.0, settings: GoToSettings | None = None,
                    on_step: Callable[[GoToCommand], None] | None = None) -> Pose:
        """Drive to (``x``, ``y``) in the odometry frame (and turn to ``theta`` rad, if
        given) with the seed's position controller. Returns the pose on arrival; raises
        :class:`GoalTimeout` (robot stopped) when not there within ``timeout`` s, and
        :class:`RobotStopped` when supervision stops the robot meanwhile. The robot must be
        enabled, and its enable renewed (:meth:`enabled`) while it drives."""
        if not (math.isfinite(timeout) and timeout > 0):
            raise ValueError(f"timeout must be a positive number of seconds, got {timeout!r}")
        controller = GoTo(x, y, theta, settings or self.goto_settings)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        self._stopped_event.clear()
        try:
            while True:
                if self.supervisor.state is not State.ENABLED:
                    stop = self.supervisor.last_stop
                    raise RobotStopped("go_to stopped: " + (
                        stop.describe() if stop else "the robot is not enabled"), stop)
                step = controller.step(self.odometry.pose, loop.time())
                if on_step is not None:
                    on_step(step)
                if controller.done:
                    self.stop()
                    if await self._settled(deadline) and controller.arrived(
                            self.odometry.pose):
                        return self.odometry.pose
                    # It rolled out of the tolerance while stopping: go on from here.
                    controller = GoTo(x, y, theta, controller.settings)
                    continue
                if loop.time() > deadline:
                    self.stop()
                    raise GoalTimeout(
                        f"not at ({x:g}, {y:g}) after {timeout:g} s: {step.distance:.2f} m "
                        f"away, {math.degrees(step.heading_error):.0f}° off, phase "
                        f"{step.phase.value}")
                self.drive(step.v, step.omega)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._stopped_event.wait(), self.control_period)
        except BaseException:
            if self.supervisor.state is State.ENABLED:
                self.stop()
            raise

    async def _settled(self, deadline: float) -> bool:
        """Wait until the wheels have stopped (or ``deadline``): an arrival counts at rest."""
        loop = asyncio.get_running_loop()
        while loop.time() < deadline:
            if abs(self.odometry.v) < SETTLED_SPEED and abs(self.odometry.omega) < SETTLED_TURN:
                return True
            if self.supervisor.state is not State.ENABLED:
                return False
            await asyncio.sleep(self.control_period)
        return False

    # --- state ----------------------------------------------------------------------------

    @property
    def pose(self) -> Pose:
        return self.odometry.pose

    @property
    def odometry_state(self) -> OdometryState:
        return self.odometry.state

    def joint_states(self, samples: Mapping[str, Telemetry] | None = None
                     ) -> JointStates | None:
        """The four wheels from each board's latest sample, or from ``samples`` (board →
        sample; ``None`` until every board has one): rad, rad/s, N·m, forward-positive."""
        return joint_states(self.description, self.latest if samples is None else samples,
                            {key: 10 * pulses for key, pulses in self.resolution.items()},
                            self.torque_coef, self._count_offset)

    def health(self, now: float | None = None) -> list[Status]:
        """One status per board and one for supervision. Wire use is measured between
        calls (``now`` on the loop's clock; default: now)."""
        now = self._now() if now is None else now
        statuses = []
        for name, link in self.links.items():
            stats = link.stats
            latest = self.latest.get(name)
            statuses.append(board_status(
                name, link.url, alive=link.board_alive,
                enabled=bool(latest is not None and latest.a.enabled),
                stats=stats,
                wire=self._wire[name].update(now, stats.bytes_received, stats.bytes_sent),
                fault=self.supervisor.blocked.get(name)))
        statuses.append(supervision_status(self.supervisor.state, self.supervisor.last_stop,
                                           self.supervisor.blocked))
        return statuses

    def truth(self) -> dict[str, Any] | None:
        """The true pose when the robot is emulated (``None`` on hardware)."""
        for link in self.links.values():
            source = link.get_extra_info(TRUTH_EXTRA)
            if source is not None:
                record: dict[str, Any] = source()
                return record
        return None

    def _now(self) -> float:
        loop = self._loop or asyncio.get_running_loop()
        return loop.time()

    def _ensure_started(self) -> None:
        if not self._started:
            raise RobotError("the robot is not started: use `async with robot:` or "
                             "`await robot.start()`")

    def wheel_resolution(self, board: str, channel: int) -> int:
        """Encoder pulses per turn, as read from the board at start."""
        return self.resolution[(board, channel)]

