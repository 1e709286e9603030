"""What drives the wheels now, sans-I/O: the robot's one command arbiter.

Every command that reaches the boards' references passes here — a body command
(:meth:`CommandArbiter.drive`, the go-to controller's too), wheel references
(:meth:`CommandArbiter.wheels`), a velocity command through the limits
(:meth:`CommandArbiter.velocity`, ROS's ``cmd_vel``), a stop — and the arbiter answers
with the references to send (:class:`Send`). Beside it, what a teleop's commands need:

- **limits**: the robot's speed limits (a command beyond one scaled keeping its curvature)
  and diff_drive_controller's acceleration and jerk limits (:mod:`.limits`): a velocity
  command under those is a *ramp*, followed one control step at a time
  (:meth:`CommandArbiter.control_step`, on the boards' clock), from what the robot drives
  when it began; any other command or a stop ends it;
- **timed commands** (:meth:`CommandArbiter.timed`): one older than
  :attr:`CommandArbiter.command_timeout` brings the wheels to rest (within the
  deceleration limits while ramping), unless another source took over;
- **the held command** (:meth:`CommandArbiter.hold`): a timed command that came while the
  robot was not enabled (its enable, on a topic of its own, may come just after it), given
  back when the robot is enabled within the timeout;
- **enable renewal** (:attr:`CommandArbiter.renew_period`): when to renew the enable by
  itself (the robot's :meth:`~fpgalink.robot.Robot.enabled` block, or a node without the
  deadman), and **auto-enable** (:attr:`CommandArbiter.auto_enable`): a timed command asks
  for the enable.

Time is passed in: ``now`` on the caller's clock (s) for timers, the first board's sample
time ``t_us`` for control steps. :meth:`get_timer` / :meth:`handle_timer` as the other
sans-I/O parts have them.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum

from fpgalink.protocol import LocalProtocolError
from fpgalink.protocol.robot import RobotDescription, SkidSteer
from fpgalink.robot.drive import WheelCommand, wheel_command
from fpgalink.robot.limits import AxisLimits, SpeedLimiter

__all__ = ["MAX_CONTROL_STEP_S", "CommandArbiter", "CommandNotice", "Commanded", "Held", "Send",
           "Source", "Taken"]

#: The longest control step a ramp takes (s): a stalled host (or a board clock that started
#: again) would otherwise make its whole stall one step.
MAX_CONTROL_STEP_S = 0.1
_WRAP_US = 1 << 32


class Source(Enum):
    """Who drives the wheels."""

    DRIVE = "drive"  #: a body command (``Robot.drive``: the CLI, campaigns)
    WHEELS = "wheels"  #: wheel references (``Robot.set_wheel_references``, ``wheel_refs``)
    VELOCITY = "velocity"  #: a velocity command through the limits (``cmd_vel``)
    GOAL = "goal"  #: the go-to controller


@dataclass(frozen=True, slots=True)
class Send:
    """References for every board, now: board → (A, B), deg/s in each board's own sign
    (N·m in torque control). ``command``: the body command they carry (``None`` for wheel
    references and for a stop)."""

    references: Mapping[str, tuple[float, float]]
    command: WheelCommand | None
    source: Source | None


@dataclass(frozen=True, slots=True)
class Held:
    """A timed command taken while the robot was not enabled."""

    source: Source
    value: tuple[float, float] | Mapping[str, float]
    at: float


@dataclass(frozen=True, slots=True)
class CommandNotice:
    """What the robot's commands did by themselves: a timed command ran out (the wheels to
    rest), a held command sent once the robot was enabled (``command``: the body command
    it drove) or not sent. ``fault``: worth a warning."""

    at: float
    text: str
    command: WheelCommand | None = None
    fault: bool = True


class Taken(Enum):
    """What became of a teleop's command."""

    DRIVEN = "driven"  #: sent to the boards now
    RAMPING = "ramping"  #: followed under the acceleration limits, one control step a time
    HELD = "held"  #: the robot is not enabled: kept, sent if it is enabled in time
    REFUSED = "refused"  #: the robot could not be enabled for it (a board not ready)


@dataclass(frozen=True, slots=True)
class Commanded:
    """A teleop's command's outcome: ``command`` the body command driven (``DRIVEN`` by a
    velocity command), ``reason`` why it was held or refused."""

    taken: Taken
    command: WheelCommand | None = None
    reason: str = ""


class CommandArbiter:
    """See the module docstring. The owner sends each :class:`Send` it returns, calls
    :meth:`stopped` when supervision disabled every board, and runs the timers."""

    def __init__(self, description: RobotDescription, kinematics: SkidSteer | None = None
                 ) -> None:
        self.description = description
        self.kinematics = kinematics or description.kinematics()
        self.limiter = SpeedLimiter()
        #: a timed command older than this brings the wheels to rest (``None``: never)
        self.command_timeout: float | None = None
        #: a timed command taken while not enabled is held this long (``None``: the
        #: command timeout; 0: not held)
        self.hold_s: float | None = None
        #: a timed command asks for the enable (no deadman: ROS's ``require_enable`` off)
        self.auto_enable = False
        #: renew the enable this often while enabled (``None``: the caller renews)
        self.renew_period: float | None = None
        #: board time between a ramp's control steps (s): ROS's ``joint_state_rate``
        self.control_period = 0.0
        self.command: WheelCommand | None = None  #: the body command driven now
        self.source: Source | None = None  #: who drove last (``None``: at rest, stopped)
        self.held: Held | None = None
        self._ramp: tuple[float, float] | None = None  #: the velocity command followed
        self._wheels_drove = False  #: wheel references drove since the last ramp began
        self._step_t_us: int | None = None  #: the board time of the last control step
        self._timed_at: float | None = None  #: when the last non-zero timed command came
        self._renew_at: float | None = None

    # --- what the robot is ----------------------------------------------------------------

    def set_description(self, description: RobotDescription, kinematics: SkidSteer) -> None:
        """Drive with another description (its speed limits) or kinematics from now on."""
        self.description, self.kinematics = description, kinematics

    def set_limits(self, linear: AxisLimits, angular: AxisLimits,
                   file_limits: tuple[float, float]) -> None:
        """diff_drive_controller's limits per axis; their ``max_velocity`` (at most the
        robot file's ``file_limits``, m/s and rad/s) also bounds every body command."""
        self.limiter.linear, self.limiter.angular = linear, angular
        speeds = (min(linear.max_velocity, file_limits[0]),
                  math.degrees(min(angular.max_velocity, file_limits[1])))
        if speeds != (self.description.max_linear_speed, self.description.max_angular_speed):
            self.description = dataclasses.replace(
                self.description, max_linear_speed=speeds[0], max_angular_speed=speeds[1])

    # --- commands ---------------------------------------------------------------------------

    def drive(self, v: float, omega: float, source: Source = Source.DRIVE) -> Send:
        """A body command, now: limits scale it keeping its curvature; non-finite values
        raise :class:`~fpgalink.protocol.LocalProtocolError`. Ends a ramp under way."""
        command = wheel_command(self.description, v, omega, self.kinematics)
        self._take_over(source)
        self.command = command
        return Send(command.references, command, source)

    def check_wheels(self, references: Mapping[str, float]) -> None:
        """:class:`~fpgalink.protocol.LocalProtocolError` for an unknown wheel or a
        non-finite value."""
        names = {w.name for w in self.description.wheels}
        unknown = sorted(set(references) - names)
        if unknown:
            raise LocalProtocolError(f"no wheel {', '.join(unknown)}: the robot's are "
                                     f"{', '.join(sorted(names))}")
        if not all(math.isfinite(v) for v in references.values()):
            raise LocalProtocolError(f"wheel references must be finite, got {dict(references)}")

    def wheels(self, references: Mapping[str, float]) -> Send:
        """Wheel references by wheel name (``FL``…), forward-positive, in the boards' unit
        (deg/s; N·m in torque control); wheels not named get 0. An unknown wheel or a
        non-finite value raises :class:`~fpgalink.protocol.LocalProtocolError`."""
        self.check_wheels(references)
        refs: dict[str, list[float]] = {b: [0.0, 0.0] for b in self.description.boards}
        for wheel in self.description.wheels:
            refs[wheel.board][wheel.channel - 1] = references.get(wheel.name, 0.0) \
                * wheel.forward
        self._take_over(Source.WHEELS)
        self._wheels_drove = True
        self.command = None
        return Send({b: (a, c) for b, (a, c) in refs.items()}, None, Source.WHEELS)

    def velocity(self, v: float, omega: float, measured: tuple[float, float]) -> Send | None:
        """A velocity command through the limits: beyond ``min_velocity``/``max_velocity``
        scaled keeping its curvature (non-finite: refused); without acceleration or jerk
        limits driven now (the :class:`Send`), with them a ramp (``None``: driven by
        :meth:`control_step`), begun from what the robot drives (after wheel references,
        ``measured``: the body's speeds)."""
        if not (math.isfinite(v) and math.isfinite(omega)):
            raise LocalProtocolError(f"a velocity command must be finite, got ({v}, {omega})")
        v, omega = self.limiter.target(v, omega)
        if not self.limiter.rate_limited:
            self._ramp = None
            return self.drive(v, omega, Source.VELOCITY)
        if self._ramp is None or self.source is not Source.VELOCITY:
            now = measured if self._wheels_drove else (
                (self.command.v, self.command.omega) if self.command is not None
                else (0.0, 0.0))
            self._wheels_drove = False
            if now != self.limiter.last:
                self.limiter.reset(*now)
            self.source = Source.VELOCITY
        self._ramp = (v, omega)
        return None

    def stop(self) -> Send:
        """Zero references to every board (the robot stays enabled)."""
        self._take_over(None)
        self.command = None
        return Send({b: (0.0, 0.0) for b in self.description.boards}, None, None)

    def stopped(self) -> None:
        """Supervision disabled every board (the firmware clears its references): nothing
        drives, a ramp ends (the next velocity command starts from rest)."""
        self._take_over(None)
        self.command = None

    def _take_over(self, source: Source | None) -> None:
        if source is not Source.VELOCITY:
            self._ramp = None
        if source not in (Source.VELOCITY, Source.WHEELS):
            self._timed_at = None
        self.source = source

    @property
    def ramping(self) -> bool:
        """A velocity command is being followed under the rate limits."""
        return self._ramp is not None

    def control_step(self, t_us: int) -> Send | None:
        """The first board's sample at ``t_us``: one step of the ramp towards the velocity
        command when :attr:`control_period` of board time has passed since the last step;
        the :class:`Send` when it changes what the boards have."""
        last = self._step_t_us
        if last is not None and (t_us - last) % _WRAP_US < self.control_period * 1e6 - 500:
            return None
        self._step_t_us = t_us
        if self._ramp is None:
            self.limiter.reset(*self.limiter.last)  # held: no acceleration left over
            return None
        if last is None:
            return None
        dt = min(((t_us - last) % _WRAP_US) / 1e6,
                 max(MAX_CONTROL_STEP_S, 1.5 * self.control_period))
        before = self.limiter.last
        v, omega = self.limiter.step(*self._ramp, dt)
        send = None
        if (v, omega) != before:  # else the boards have it already
            command = wheel_command(self.description, v, omega, self.kinematics)
            # The robot's own limits (its wheels' top speed) may have scaled it.
            self.limiter.follow(command.v, command.omega)
            self.command = command
            send = Send(command.references, command, Source.VELOCITY)
        if self._ramp == self.limiter.last == (0.0, 0.0):
            self._ramp = None  # at rest: the next velocity command starts from here
        return send

    # --- timed and held commands ------------------------------------------------------------

    def timed(self, now: float, zero: bool) -> None:
        """The command just driven (velocity or wheels) is timed from ``now``; a zero one
        needs no timeout."""
        self._timed_at = None if zero else now

    def hold(self, source: Source, value: tuple[float, float] | Mapping[str, float],
             now: float) -> None:
        """Keep a timed command taken while the robot was not enabled."""
        self.held = Held(source, value, now)

    def take_held(self, now: float) -> Held | None:
        """The held command, if it is still fresh (given once)."""
        held, self.held = self.held, None
        window = self.command_timeout if self.hold_s is None else self.hold_s
        if held is None or window is None or now - held.at > window:
            return None
        return held

    # --- timers -----------------------------------------------------------------------------

    def enabled(self, now: float) -> None:
        """The robot is enabled (or its enable renewed) at ``now``."""
        self._renew_at = None if self.renew_period is None else now + self.renew_period

    def get_timer(self) -> float | None:
        """When :meth:`handle_timer` must be called next, or ``None``."""
        due = [t for t in (self._renew_at, self._timeout_at()) if t is not None]
        return min(due, default=None)

    def _timeout_at(self) -> float | None:
        if self._timed_at is None or self.command_timeout is None:
            return None
        return self._timed_at + self.command_timeout

    def handle_timer(self, now: float, enabled: bool
                     ) -> tuple[bool, CommandNotice | None, Send | None]:
        """(renew the enable now, what a timed-out command did, what to send for it)."""
        renew = False
        if self._renew_at is not None and now >= self._renew_at:
            self._renew_at = None
            renew = enabled and self.renew_period is not None
        timeout_at = self._timeout_at()
        if timeout_at is None or now < timeout_at:
            return renew, None, None
        notice = CommandNotice(now, f"no command for {self.command_timeout:g} s: wheels to "
                                    "rest")
        self._timed_at = None
        if self._ramp is not None and self.limiter.rate_limited:
            self._ramp = (0.0, 0.0)  # braking within the limits, as diff_drive_controller
            return renew, notice, None
        return renew, notice, self.stop()
