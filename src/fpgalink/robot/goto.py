"""Go to a point (the seed's position controller, §3.5 Algorithm 1), sans-I/O: pose and time
in, a body command out.

Algorithm 1 turns towards the goal while the heading error exceeds ``Tr_α``, then drives
with a PI distance loop whose input is weighted by the inverse of the heading error while a
PI heading loop keeps correcting, and stops within ``Tr``. Where the pseudo-code is loose,
this module decides (docs/robot.md says why):

* the heading error is wrapped to the shortest turn (the prose asks for it) and compared by
  magnitude; turning starts above ``Tr_α`` and ends below ``Tr_α/2`` (hysteresis, so the
  robot does not chatter between turning and driving at the boundary);
* the distance loop's input is ``d · Tr_α / (Tr_α + |e_α|)``: inversely weighted by the
  heading error as the seed says, but bounded (the literal ``d/e_α`` diverges as the error
  vanishes);
* within ``near_radius`` of the goal the direction to it is ill-defined (it swings as the
  robot passes), so while the goal lies on the robot's line (within 0.7·Tr sideways) the
  heading is held and the distance loop drives the signed distance along the heading (an
  overshoot backs up instead of turning round); off the line, it turns to face the goal;
* with a final heading, the robot then turns in place to it (the seed's algorithm takes
  ``α_t`` but never uses it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from fpgalink.protocol.robot import Pose, wrap_angle

__all__ = ["GoTo", "GoToCommand", "GoToSettings", "Phase"]


class Phase(Enum):
    TURN = "turn"  #: turning in place towards the goal
    DRIVE = "drive"  #: driving towards it, correcting the heading
    ALIGN = "align"  #: at the goal, turning to the final heading
    ARRIVED = "arrived"


@dataclass(frozen=True, slots=True)
class GoToSettings:
    position_tolerance: float = 0.05  #: Tr, m
    heading_tolerance: float = math.radians(10.0)  #: Tr_α, rad
    final_heading_tolerance: float = math.radians(3.0)  #: rad, for the final heading
    max_speed: float = 0.25  #: V_max, m/s
    max_turn_rate: float = math.radians(25.0)  #: Ω_max, rad/s
    kp_distance: float = 0.8  #: 1/s
    ki_distance: float = 0.05  #: 1/s²
    kp_heading: float = 1.5  #: 1/s
    ki_heading: float = 0.1  #: 1/s²
    near_radius: float = 0.15  #: m: within it, hold the heading and drive along it

    def __post_init__(self) -> None:
        for name in ("position_tolerance", "heading_tolerance", "final_heading_tolerance",
                     "max_speed", "max_turn_rate", "kp_distance", "kp_heading",
                     "near_radius"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        for name in ("ki_distance", "ki_heading"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number ≥ 0, got {value!r}")


@dataclass(frozen=True, slots=True)
class GoToCommand:
    v: float  #: m/s
    omega: float  #: rad/s
    phase: Phase
    distance: float  #: m to the goal
    heading_error: float  #: rad


class _PI:
    """A PI loop with its output limited and the integral frozen while limited."""

    def __init__(self, kp: float, ki: float, limit: float) -> None:
        self.kp, self.ki, self.limit = kp, ki, limit
        self.integral = 0.0

    def reset(self) -> None:
        self.integral = 0.0

    def __call__(self, error: float, dt: float) -> float:
        candidate = self.integral + error * dt
        out = self.kp * error + self.ki * candidate
        if abs(out) <= self.limit:
            self.integral = candidate
            return out
        return math.copysign(self.limit, out)


class GoTo:
    """``step(pose, now)`` → the body command for now, until the phase is ``ARRIVED``."""

    def __init__(self, x: float, y: float, theta: float | None = None,
                 settings: GoToSettings | None = None) -> None:
        for name, value in (("x", x), ("y", y), ("theta", 0.0 if theta is None else theta)):
            if not math.isfinite(value):
                raise ValueError(f"the goal's {name} must be a finite number, got {value!r}")
        self.x, self.y = float(x), float(y)
        self.theta = None if theta is None else wrap_angle(theta)
        self.settings = settings or GoToSettings()
        s = self.settings
        self._distance = _PI(s.kp_distance, s.ki_distance, s.max_speed)
        self._heading = _PI(s.kp_heading, s.ki_heading, s.max_turn_rate)
        self.phase = Phase.TURN
        self._last: float | None = None

    @property
    def done(self) -> bool:
        return self.phase is Phase.ARRIVED

    def arrived(self, pose: Pose) -> bool:
        """``pose`` is within the tolerances of the goal (position, and final heading)."""
        s = self.settings
        if math.hypot(self.x - pose.x, self.y - pose.y) >= s.position_tolerance:
            return False
        return self.theta is None or abs(wrap_angle(self.theta - pose.theta)) < \
            s.final_heading_tolerance

    def _enter(self, phase: Phase) -> None:
        if phase is not self.phase:
            self.phase = phase
            self._distance.reset()
            self._heading.reset()

    def step(self, pose: Pose, now: float) -> GoToCommand:
        s = self.settings
        dt = 0.0 if self._last is None else max(0.0, now - self._last)
        self._last = now
        dx, dy = self.x - pose.x, self.y - pose.y
        distance = math.hypot(dx, dy)
        if self.phase in (Phase.TURN, Phase.DRIVE) and distance < s.position_tolerance:
            self._enter(Phase.ALIGN if self.theta is not None else Phase.ARRIVED)
        if self.phase is Phase.ALIGN:
            assert self.theta is not None
            error = wrap_angle(self.theta - pose.theta)
            if abs(error) < s.final_heading_tolerance:
                self._enter(Phase.ARRIVED)
            else:
                return GoToCommand(0.0, self._heading(error, dt), self.phase, distance, error)
        if self.phase is Phase.ARRIVED:
            return GoToCommand(0.0, 0.0, self.phase, distance, 0.0)

        heading_error = wrap_angle(math.atan2(dy, dx) - pose.theta)
        lateral = distance * math.sin(heading_error)
        if (distance < s.near_radius and self.phase is Phase.DRIVE
                and abs(lateral) <= 0.7 * s.position_tolerance):
            # Close in and on line: hold the heading, drive the signed distance along it.
            along = distance * math.cos(heading_error)
            return GoToCommand(self._distance(along, dt), 0.0, self.phase, distance,
                               heading_error)
        if self.phase is Phase.TURN and abs(heading_error) <= s.heading_tolerance / 2:
            self._enter(Phase.DRIVE)
        elif self.phase is Phase.DRIVE and abs(heading_error) > s.heading_tolerance:
            self._enter(Phase.TURN)
        omega = self._heading(heading_error, dt)
        if self.phase is Phase.TURN:
            return GoToCommand(0.0, omega, self.phase, distance, heading_error)
        weight = s.heading_tolerance / (s.heading_tolerance + abs(heading_error))
        return GoToCommand(self._distance(distance * weight, dt), omega, self.phase,
                           distance, heading_error)
