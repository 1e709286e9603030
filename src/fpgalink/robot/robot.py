"""The robot over asyncio: one :class:`~fpgalink.aio.Link` per board, with the sans-I/O
parts (:mod:`.arbiter`, :mod:`.odometry`, :mod:`.supervision`, :mod:`.goto`,
:mod:`.stamping`) fed from the links' telemetry and events and the loop's clock.

Everything that drives the wheels goes through the robot's command arbiter
(:mod:`.arbiter`): body commands, wheel references, velocity commands under limits, held
and timed commands, the enable's renewal. Nothing above the robot writes to its links.

Faults stop it and say why (``docs/robot.md``, Faults): :mod:`.recovery` reads the links'
events; a board that restarts is reconfigured by its link and re-anchored here (its
encoder counts and clock start again, which is not motion), and is not ready until that is
confirmed; any exception in the robot's own tasks and callbacks stops it for good.

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
from collections.abc import AsyncIterator, Callable, Iterator, Mapping
from typing import Any

from fpgalink.aio.link import Link, Subscription
from fpgalink.errors import FpgalinkError
from fpgalink.events import Event, RequestDone, StatusEvent
from fpgalink.protocol import Telemetry
from fpgalink.protocol.robot import Pose, RobotDescription, SkidSteer
from fpgalink.robot import goal, setup
from fpgalink.robot.arbiter import CommandArbiter, CommandNotice, Send, Source
from fpgalink.robot.boards import TRUTH_EXTRA, Boards, open_links
from fpgalink.robot.drive import WheelCommand, changed_kinematics
from fpgalink.robot.errors import GoalTimeout, RobotClosed, RobotError, RobotStopped
from fpgalink.robot.feed import SetFeed
from fpgalink.robot.following import TelemetryFollowers
from fpgalink.robot.goto import GoToCommand, GoToSettings
from fpgalink.robot.health import Status, supervision_status
from fpgalink.robot.joints import JointStates
from fpgalink.robot.limits import AxisLimits
from fpgalink.robot.odometry import Odometry, OdometryState
from fpgalink.robot.recovery import BoardNotice, BoardRecovery
from fpgalink.robot.stamping import SampleStamper, StampedSet
from fpgalink.robot.supervision import (
    DEADMAN_S,
    Action,
    NotReady,
    State,
    SupervisionEvent,
    Supervisor,
)
from fpgalink.robot.teleop import Teleop
from fpgalink.robot.timers import LoopTimers
from fpgalink.robot.tracking import Tracking

__all__ = ["TRUTH_EXTRA", "GoalTimeout", "Robot", "RobotClosed", "RobotError", "RobotStopped"]

#: How often :meth:`Robot.enabled` renews the deadman (well inside the 0.5 s).
RENEW_S = 0.1
#: Running time a caller gets to renew when the deadman's deadline passed while this loop
#: was not running (a blocked or starved process): one and a half renewal periods.
DEADMAN_GRACE_S = 1.5 * RENEW_S
START_TIMEOUT_S = setup.START_TIMEOUT_S
QUIET_TIMEOUT_S = setup.QUIET_TIMEOUT_S

Notice = BoardNotice | CommandNotice


class Robot:
    """A skid-steered robot whose boards are reached through ``links`` (board name → link,
    as the description names them). The robot owns the links: it opens and closes them,
    and it alone writes to them."""

    def __init__(self, description: RobotDescription, links: Mapping[str, Link], *,
                 deadman_s: float = DEADMAN_S, control_period: float = 0.02,
                 goto_settings: GoToSettings | None = None, allow_mismatch: bool = False) -> None:
        missing = sorted(set(description.boards) - set(links))
        extra = sorted(set(links) - set(description.boards))
        if missing or extra:
            raise RobotError(f"the robot's boards are {', '.join(description.boards)}; "
                             f"links given for {', '.join(sorted(links)) or 'none'}")
        if not (math.isfinite(control_period) and 0 < control_period <= 1):
            raise ValueError(f"control_period must be in (0, 1] s, got {control_period!r}")
        self.description = description
        #: the boards over their links (``links``: the same links, by board name)
        self.boards = Boards(links)
        self.links = self.boards.links
        self.control_period = control_period
        self.goto_settings = goto_settings or GoToSettings(
            max_speed=description.max_linear_speed,
            max_turn_rate=description.max_angular_speed_rad)
        self.kinematics = description.kinematics()
        self.odometry = Odometry(description, self.kinematics)
        self.supervisor = Supervisor(description.boards, deadman_s)
        self.tracking = Tracking(description, self.odometry)
        #: a teleop's commands (ROS's cmd_vel, wheel_refs): timed, held, auto-enabling
        self.teleop = Teleop(self, self._now, self._arm_commands)
        self.arbiter = CommandArbiter(description, self.kinematics)
        self.recovery = BoardRecovery(
            description, self.supervisor, carry_out=self._carry_out, now=self._now,
            guarded=self._guarded, restarted=self.tracking.restarted,
            read_back=self.tracking.read_back, notify=self._notify,
            allow_mismatch=allow_mismatch)
        #: pulses per turn, TorqueCoef (by board, channel), each board's latest sample
        self.resolution, self.torque_coef = self.tracking.resolution, self.tracking.torque_coef
        self.latest = self.tracking.latest
        #: the exception that stopped the robot for good, if one did
        self.failure: BaseException | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._followers = TelemetryFollowers(self.boards, self.tracking, self.arbiter,
                                             description.boards[0], self._guarded)
        self._removers: list[Callable[[], None]] = []
        self._feeds: set[Subscription[SupervisionEvent]] = set()
        self._set_feeds: set[SetFeed] = set()
        self._listeners: list[Callable[[Notice], None]] = []
        self._timers = LoopTimers()  #: "deadman" (the supervisor's), "commands" (arbiter's)
        self._streaming_before: dict[str, int | float] = {}
        self._started = self._closed = False
        #: set when supervision stops the robot (a waiter clears it first)
        self.stopped = asyncio.Event()
        for name, link in self.links.items():
            # Synchronously: the other boards get RD in the very callback that notices. For
            # the robot's life (its readers hear the links from their first word to their
            # close); the robot reacts only while started.
            link.on_event(functools.partial(self._on_link_event, name, link))

    @classmethod
    def open(cls, description: RobotDescription, ports: Mapping[str, str], *,
             baud: int = 1_000_000, stale_periods: int = 50, wire_crc: bool = False,
             identity_seed: int | None = None, read_latency: float | None = None,
             **options: Any) -> Robot:
        """A robot over links to ``ports`` (board name → URL): ``async with Robot.open(…)``.
        The links' settings: :func:`~fpgalink.robot.boards.open_links` (``read_latency``:
        docs/robot.md, :meth:`read_now`); ``options`` go to the robot (deadman_s,
        control_period, goto_settings, allow_mismatch)."""
        return cls(description, open_links(ports, baud=baud, stale_periods=stale_periods,
                                           wire_crc=wire_crc, identity_seed=identity_seed,
                                           read_latency=read_latency),
                   **options)

    # --- lifecycle ------------------------------------------------------------------------

    async def start(self) -> Robot:
        """Open the links, wait for every board, ask each who it is (docs/protocol.md §8:
        ``IdentityMismatch`` unless ``allow_mismatch``), load the description's parameters,
        read each wheel's encoder resolution back from its board, turn telemetry on."""
        self._timers.start(asyncio.get_running_loop())
        try:
            await self.boards.open()
            await self._wait_for_boards()
            self._streaming_before, readings = await setup.set_up(
                self.links, self.description, self.recovery.allow_mismatch)
        except BaseException:
            await self.boards.close()
            raise
        for (name, channel, param), value in readings.items():
            self.tracking.read_back(name, channel, param, value)
        for name, link in self.links.items():
            self.supervisor.board_alive(name, link.board_alive, self._now())
            self._tasks.append(self._followers.follow(name, link))
            self._removers.append(link.add_listener(functools.partial(self._on_confirmed,
                                                                      name)))
        self._started = True
        return self

    async def _wait_for_boards(self) -> None:  # a test's hook
        await setup.wait_for_boards(self.links)

    async def close(self) -> None:
        """Disable every board, restore their telemetry setting, close the links. Every
        command after it raises :class:`RobotClosed`; closing again does nothing."""
        self._timers.close()
        if self.supervisor.state is State.ENABLED:
            self._carry_out(self.supervisor.request_disable(self._now()))
        self._closed = True
        for remove in self._removers:
            remove()
        self._removers.clear()
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()
        await self.recovery.close()
        await self.boards.restore(self._streaming_before)
        await self.boards.close()
        for feed in self._feeds:
            feed.finish()
        for set_feed in self._set_feeds:
            set_feed.finish()
        self._feeds.clear()
        self._set_feeds.clear()

    async def __aenter__(self) -> Robot:
        return await self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # --- supervision ----------------------------------------------------------------------

    def enable(self) -> None:
        """Enable the robot, or renew the enable: it must be renewed at least every
        ``deadman_s`` (0.5 s) or every board is disabled. :class:`RobotStopped` (from
        :class:`~fpgalink.robot.supervision.NotReady`) when a board is not answering, or
        when a board's link refused the enable (the others are disabled again). A command
        held while the robot was not enabled is driven now, if still fresh."""
        self._ensure_started()
        now = self._now()
        was = self.supervisor.state
        try:
            actions = self.supervisor.request_enable(now)
        except NotReady as exc:
            self._carry_out(exc.actions)
            raise RobotStopped(str(exc), self.supervisor.last_stop) from None
        self._carry_out(actions)
        if self.supervisor.state is not State.ENABLED:  # a board's link refused it
            stop = self.supervisor.last_stop
            raise RobotStopped(stop.describe() if stop else "the enable failed", stop)
        self.arbiter.enabled(now)
        self._arm_commands()
        if was is not State.ENABLED:
            notice = self.teleop.release(now)
            if notice is not None:
                self._notify(notice)

    def disable(self) -> None:
        """Disable every board now (``RD``); a held command is dropped."""
        self._ensure_started()
        self.arbiter.held = None
        self._carry_out(self.supervisor.request_disable(self._now()))

    @contextlib.asynccontextmanager
    async def enabled(self, renew_every: float = RENEW_S) -> AsyncIterator[Robot]:
        """Enabled while the block runs: the deadman is renewed every ``renew_every`` s
        while the robot is enabled (so a stalled loop still lets it lapse), and the robot
        is stopped and disabled on the way out, however the block ends."""
        self.enable()
        before = self.arbiter.renew_period
        self.keep_enabled(renew_every)
        try:
            yield self
        finally:
            self.keep_enabled(before)
            if self.supervisor.state is State.ENABLED:
                with contextlib.suppress(FpgalinkError):
                    self.stop()
                self.disable()

    def keep_enabled(self, every: float | None) -> None:
        """Renew the enable every ``every`` s while enabled (``None``: the caller renews
        it); a fault still stops it, and enabling again is the caller's."""
        self.arbiter.renew_period = every
        if self.supervisor.state is State.ENABLED:
            self.arbiter.enabled(self._now())
        self._arm_commands()

    @property
    def state(self) -> State:
        return self.supervisor.state

    @property
    def last_stop(self) -> SupervisionEvent | None:
        return self.supervisor.last_stop

    def events(self, maxsize: int = 64) -> Subscription[SupervisionEvent]:
        """Supervision events (enabled, stopped and why) as an async iterator."""
        feed: Subscription[SupervisionEvent] = Subscription(maxsize, self._feeds.discard)
        self._feeds.add(feed)
        return feed

    def on_notice(self, callback: Callable[[Notice], None]) -> Callable[[], None]:
        """Call ``callback`` with what the boards' links notice (:class:`BoardNotice`, from
        their first word to their close) and what the robot's commands did by themselves
        (:class:`CommandNotice`), synchronously, as it happens. Returns a remover."""
        self._listeners.append(callback)
        return lambda: self._listeners.remove(callback) \
            if callback in self._listeners else None

    def _on_link_event(self, name: str, link: Link, event: StatusEvent) -> None:
        self.recovery.on_link_event(name, link, event, self._started and not self._closed)

    def _notify(self, notice: Notice) -> None:
        for listener in list(self._listeners):
            listener(notice)

    def _carry_out(self, actions: list[Action]) -> None:
        for action in actions:
            if action is Action.ENABLE_ALL:
                refused = self.boards.enable_all()
                if refused is not None:  # said and stopped, every board disabled again
                    name, exc = refused
                    self._carry_out(self.supervisor.enable_failed(name, self._now(),
                                                                  str(exc)))
                    return
            elif action is Action.DISABLE_ALL:
                self.boards.disable_all()
        if any(a is Action.DISABLE_ALL for a in actions):
            self.arbiter.stopped()
        for event in self.supervisor.events():
            if event.state is State.DISABLED:
                self.stopped.set()
            for feed in self._feeds:
                feed.put(event)
        self._arm_deadman()

    def _arm_deadman(self) -> None:
        if not self._closed:
            self._timers.arm("deadman", self.supervisor.get_timer(), self._on_deadman)

    def _arm_commands(self) -> None:
        if not self._closed:
            self._timers.arm("commands", self.arbiter.get_timer(), self._on_commands)

    def _on_deadman(self) -> None:
        self._timers.fired("deadman")
        # A deadline that passed while this loop was not running (the process blocked or
        # starved): the deadman measures the caller's running time without a renewal, and
        # the caller had none (its renewal is queued behind this callback). It gets one
        # renewal period of running time, then the judgement: a caller that really stopped
        # renewing is still stopped, that much later; a stalled host's boards are stopped
        # by their own watchdog meanwhile, and its link says so (WATCHDOG_LAPSED).
        if self._timers.grace("deadman", self.supervisor.get_timer(), RENEW_S,
                              DEADMAN_GRACE_S, self._on_deadman):
            return
        with self._guarded("the deadman timer"):
            self._carry_out(self.supervisor.handle_timer(self._now()))

    def _on_commands(self) -> None:
        self._timers.fired("commands")
        with self._guarded("the command timer"):
            now = self._now()
            renew, timeout, send = self.arbiter.handle_timer(
                now, self.supervisor.state is State.ENABLED)
            if timeout is not None:
                self._notify(timeout)
            if send is not None:
                self.boards.send_each(send.references)
            if renew:
                with contextlib.suppress(RobotStopped):
                    self.enable()
            self._arm_commands()

    @contextlib.contextmanager
    def _guarded(self, what: str) -> Iterator[None]:
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
        self.arbiter.stopped()
        self.boards.disable_at_once()  # first, before anything else can fail
        with contextlib.suppress(Exception):
            self._carry_out(self.supervisor.task_failed(self._now(), detail))

    # --- the boards' telemetry, their restarts and confirmed changes -----------------------

    async def read_now(self) -> None:
        """Take at once what the boards have sent, whatever the links' read latency: the
        robot's odometry and latest samples are then as of the boards' present (on an
        in-process robot, up to one catch-up slice behind: docs/robot.md)."""
        self._ensure_started()
        await self._followers.read_now()

    def _on_confirmed(self, board: str, event: Event) -> None:
        """A parameter set through this robot's links changed a wheel's encoder resolution
        or torque coefficient: odometry and joint states follow the board (every event
        comes here, each sample too: guarded only where it acts; 0 pulses: kept the last)."""
        if isinstance(event, RequestDone) and (board, event.channel) in self.resolution:
            with self._guarded(f"board {board}'s confirmations"), \
                    contextlib.suppress(ValueError):
                self.tracking.read_back(board, event.channel, event.param.name, event.value)

    def sample_sets(self, min_period: float = 0.0, clock: Callable[[float], int] | None = None,
                    maxsize: int = 4096) -> SetFeed:
        """The boards' telemetry as stamped sets (:class:`~fpgalink.robot.stamping.
        StampedSet`: one sample per board, each mapped onto ``clock``'s time, with the
        odometry then), at most one per ``min_period`` s. ``clock(received)``: when a
        sample arrived (the loop's clock, s) on the reader's clock, ns (default: the
        loop's clock in ns; 0: not started, nothing stamped)."""
        feed = SetFeed(maxsize, self._forget_sets,
                       SampleStamper(self.description.boards, min_period))
        self._set_feeds.add(feed)
        self.tracking.add_reader(feed.stamper,
                                 clock or (lambda received: round(received * 1e9)), feed.put)
        return feed

    def _forget_sets(self, feed: Subscription[StampedSet]) -> None:
        if isinstance(feed, SetFeed):
            self._set_feeds.discard(feed)
            self.tracking.remove_reader(feed.put)

    # --- driving ----------------------------------------------------------------------------

    @property
    def command(self) -> WheelCommand | None:
        """The body command driving the wheels now (``None``: wheel references, at rest)."""
        return self.arbiter.command

    def drive(self, v: float, omega: float) -> WheelCommand:
        """Drive at body speed ``v`` (m/s) and yaw rate ``omega`` (rad/s, counter-clockwise
        positive): every board gets its ``RV`` now, in this call. Limits scale the command
        keeping its curvature; non-finite values raise and nothing is sent;
        :class:`RobotStopped` unless enabled."""
        return self._drive(v, omega, Source.DRIVE)

    def _drive(self, v: float, omega: float, source: Source) -> WheelCommand:
        self._ensure_enabled()
        send = self.arbiter.drive(v, omega, source)
        self.send(send)
        assert send.command is not None
        return send.command

    def set_wheel_references(self, references: Mapping[str, float]) -> None:
        """Each named wheel's reference (``FL``…, forward-positive, deg/s; N·m in torque
        control), now, the others 0: the seed's ``/refVals``. :class:`RobotStopped` unless
        enabled; an unknown wheel or a non-finite value raises and nothing is sent."""
        self._ensure_enabled()
        self.send(self.arbiter.wheels(references))

    def stop(self) -> None:
        """Zero references to every board (still enabled)."""
        self._ensure_started()
        self.boards.send_each(self.arbiter.stop().references)

    def send(self, send: Send) -> None:
        """Send what the robot's arbiter decided (the arbiter's answer to a command)."""
        self.boards.send(send.references)

    def _ensure_enabled(self) -> None:
        self._ensure_started()
        if self.supervisor.state is not State.ENABLED:
            stop = self.supervisor.last_stop
            raise RobotStopped("the robot is not enabled" + (
                f" ({stop.describe()})" if stop else ""), stop)

    def set_limits(self, linear: AxisLimits, angular: AxisLimits) -> None:
        """diff_drive_controller's limits for velocity commands; their ``max_velocity``
        (at most the robot file's) bounds every body command from now on."""
        file_limits = (self.description.max_linear_speed,
                       self.description.max_angular_speed_rad)
        self.arbiter.set_limits(linear, angular, file_limits)

    def set_kinematics(self, **changes: float | None) -> SkidSteer:
        """Drive and compute odometry with another ``wheel_radius`` (m), ``track`` (m,
        between the left and right wheels' centres), skid-steer factor ``chi`` (≥ 1; it
        differs per surface) or a side's ``left_radius_multiplier`` /
        ``right_radius_multiplier`` from now on; the others kept. The pose so far stays.
        ``ValueError`` for a value that is not finite and positive (χ: ≥ 1), and nothing
        changes."""
        self.kinematics = changed_kinematics(self.kinematics, **changes)
        radius = self.kinematics.wheel_radius
        self.description = dataclasses.replace(self.description, wheel_radius=radius)
        self.odometry.set_kinematics(self.description, self.kinematics)
        self.arbiter.set_description(
            dataclasses.replace(self.arbiter.description, wheel_radius=radius),
            self.kinematics)
        return self.kinematics

    async def go_to(self, x: float, y: float, theta: float | None = None, *,
                    timeout: float = 60.0, settings: GoToSettings | None = None,
                    on_step: Callable[[GoToCommand], None] | None = None) -> Pose:
        """Drive to (``x``, ``y``) in the odometry frame (and turn to ``theta`` rad, if
        given) with the seed's position controller. Returns the pose on arrival; raises
        :class:`GoalTimeout` (robot stopped) when not there within ``timeout`` s, and
        :class:`RobotStopped` when supervision stops the robot meanwhile. The robot must be
        enabled, and its enable renewed (:meth:`enabled`) while it drives."""
        self._ensure_started()
        return await goal.go_to(self, x, y, theta, timeout, settings or self.goto_settings,
                                on_step)

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
        return self.tracking.joint_states(samples)

    def health(self, now: float | None = None) -> list[Status]:
        """One status per board and one for supervision. Wire use is measured between
        calls (``now`` on the loop's clock; default: now)."""
        now = self._now() if now is None else now
        return [*(self.boards.status(name, now, self.latest.get(name),
                                     self.supervisor.blocked.get(name))
                  for name in self.description.boards),
                supervision_status(self.supervisor.state, self.supervisor.last_stop,
                                   self.supervisor.blocked)]

    def truth(self) -> dict[str, Any] | None:
        """The true pose when the robot is emulated (``None`` on hardware)."""
        return self.boards.truth()

    def _now(self) -> float:
        return self._timers.now()

    def _ensure_started(self) -> None:
        if self._closed:
            raise RobotClosed("the robot is closed")
        if not self._started:
            raise RobotError("the robot is not started: use `async with robot:` or "
                             "`await robot.start()`")
