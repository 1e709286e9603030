"""Velocity, acceleration and jerk limits on body commands as ros2_control's
diff_drive_controller (ROS 2 Jazzy) applies them, sans-I/O: a command and a time step in, the
limited command out.

diff_drive_controller limits ``linear.x`` and ``angular.z`` each on its own (its
``SpeedLimiter``, control_toolbox's ``RateLimiter``), at every update of its controller
manager, from the two commands it gave before: the jerk first (only while the acceleration
grows towards the command: control_toolbox issue 240), then the acceleration, whose bounds
depend on the direction of travel, then the velocity. Its parameters per axis, each NaN when
not set, and how the unset ones follow from the others:

=============================  =====  ========================================================
parameter                      sign   unset (NaN)
=============================  =====  ========================================================
``max_velocity``               ≥ 0    no velocity limit (``min_velocity`` then ignored)
``min_velocity``               ≤ 0    ``−max_velocity``
``max_acceleration``           ≥ 0    no acceleration limit (the next three then ignored)
``max_deceleration``           ≤ 0    ``max_acceleration_reverse``: slowing down, going forward
``max_acceleration_reverse``   ≤ 0    ``−max_acceleration``: speeding up backwards
``max_deceleration_reverse``   ≥ 0    ``max_acceleration``: slowing down, going backwards
``max_jerk``                   ≥ 0    no jerk limit (``min_jerk`` then ignored)
``min_jerk``                   ≤ 0    ``−max_jerk``
=============================  =====  ========================================================

Jazzy before its 4.18 release had ``min_acceleration`` (≤ 0) instead of the deceleration and
reverse limits: the lowest acceleration whichever way the robot goes. Later Jazzy declares it
deprecated and ignores it; here it is taken as it was meant, as the default of
``max_deceleration`` and ``max_acceleration_reverse`` (with ``max_deceleration_reverse``
defaulting to ``max_acceleration``, that is exactly the old limiter). A zero acceleration or
jerk limit is refused (:func:`check_limit`): the robot could never start, or never stop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

__all__ = ["LIMIT_SIGNS", "AxisLimits", "SpeedLimiter", "check_limit", "limit_axis",
           "velocity_scale"]

NAN = math.nan

#: Each limit's sign (+1: ≥ 0, −1: ≤ 0), as Jazzy's parameter file validates them.
LIMIT_SIGNS = {
    "min_velocity": -1, "max_velocity": 1,
    "max_acceleration": 1, "max_deceleration": -1,
    "max_acceleration_reverse": -1, "max_deceleration_reverse": 1,
    "min_acceleration": -1,
    "min_jerk": -1, "max_jerk": 1,
}
#: A zero bound on these would stop a command for good: refused.
_NONZERO = frozenset(LIMIT_SIGNS) - {"min_velocity", "max_velocity"}


def check_limit(name: str, value: float) -> str | None:
    """Why ``value`` cannot be the limit ``name`` (a key of :data:`LIMIT_SIGNS`), or
    ``None`` when it can: NaN (no limit), or a finite number of the limit's sign."""
    if math.isnan(value):
        return None
    sign = LIMIT_SIGNS[name]
    wanted = ("≥ 0" if sign > 0 else "≤ 0") if name not in _NONZERO else (
        "> 0" if sign > 0 else "< 0")
    if not math.isfinite(value) or value * sign < 0 or (value == 0 and name in _NONZERO):
        why = " (0 would never let the command change that way)" \
            if value == 0 and name in _NONZERO else ""
        return f"{name} takes a finite number {wanted}, or NaN (not set); got {value!r}{why}"
    return None


@dataclass(frozen=True, slots=True)
class AxisLimits:
    """One axis's limits under diff_drive_controller's names (m/s, m/s², m/s³ for
    ``linear.x``; rad/s, rad/s², rad/s³ for ``angular.z``); NaN: not set (module doc)."""

    min_velocity: float = NAN
    max_velocity: float = NAN
    max_acceleration: float = NAN
    max_deceleration: float = NAN
    max_acceleration_reverse: float = NAN
    max_deceleration_reverse: float = NAN
    min_acceleration: float = NAN
    min_jerk: float = NAN
    max_jerk: float = NAN

    def __post_init__(self) -> None:
        for field in fields(self):
            reason = check_limit(field.name, getattr(self, field.name))
            if reason is not None:
                raise ValueError(reason)

    @property
    def has_velocity_limits(self) -> bool:
        return not math.isnan(self.max_velocity)

    @property
    def has_acceleration_limits(self) -> bool:
        return not math.isnan(self.max_acceleration)

    @property
    def has_jerk_limits(self) -> bool:
        return not math.isnan(self.max_jerk)

    @property
    def rate_limited(self) -> bool:
        """Whether a command must be followed step by step (acceleration or jerk)."""
        return self.has_acceleration_limits or self.has_jerk_limits

    def velocity_bounds(self) -> tuple[float, float]:
        """(lowest, highest) velocity; infinite where unlimited."""
        if not self.has_velocity_limits:
            return -math.inf, math.inf
        low = -self.max_velocity if math.isnan(self.min_velocity) else self.min_velocity
        return low, self.max_velocity

    def acceleration_bounds(self, previous: float) -> tuple[float, float]:
        """(lowest, highest) acceleration from a command of ``previous``: forward (> 0),
        backward (< 0) or from rest (control_toolbox's ``limit_first_derivative``)."""
        if not self.has_acceleration_limits:
            return -math.inf, math.inf
        fallback = self.min_acceleration  # Jazzy < 4.18's name for both
        reverse = self.max_acceleration_reverse
        if math.isnan(reverse):
            reverse = -self.max_acceleration if math.isnan(fallback) else fallback
        deceleration = self.max_deceleration
        if math.isnan(deceleration):
            deceleration = reverse if math.isnan(fallback) else fallback
        deceleration_reverse = self.max_deceleration_reverse
        if math.isnan(deceleration_reverse):
            deceleration_reverse = self.max_acceleration
        if previous > 0:
            return deceleration, self.max_acceleration
        if previous < 0:
            return reverse, deceleration_reverse
        return reverse, self.max_acceleration

    def jerk_bounds(self) -> tuple[float, float]:
        if not self.has_jerk_limits:
            return -math.inf, math.inf
        return (-self.max_jerk if math.isnan(self.min_jerk) else self.min_jerk), self.max_jerk


def limit_axis(wanted: float, previous: float, before: float, dt: float,
               limits: AxisLimits) -> float:
    """``wanted`` limited after the commands ``previous`` (one step of ``dt`` s ago) and
    ``before`` (two steps ago): jerk, acceleration, then velocity, as control_toolbox's
    ``RateLimiter.limit``. A non-finite ``wanted`` is taken as 0 (brought to rest within
    the limits); a ``dt`` that is not a positive finite number leaves no room to change:
    ``previous`` comes back; a non-finite ``previous`` is a stop (0). Never NaN.

    As in Jazzy, a jerk limit may carry a command a step past what was asked: it keeps the
    acceleration of the step before when the command was all but reached."""
    if not math.isfinite(wanted):
        wanted = 0.0
    if not math.isfinite(previous):
        return 0.0
    if not math.isfinite(before):
        before = previous
    low, high = limits.velocity_bounds()
    if not (math.isfinite(dt) and dt > 0):
        return previous
    v = wanted
    if limits.has_jerk_limits:
        dv, dv_before = v - previous, previous - before
        if (dv - dv_before) * dv > 0:  # the acceleration grows the way the command goes
            jerk_low, jerk_high = limits.jerk_bounds()
            v = previous + dv_before + _clamp(dv - dv_before, jerk_low * dt * dt,
                                              jerk_high * dt * dt)
    if limits.has_acceleration_limits:
        accel_low, accel_high = limits.acceleration_bounds(previous)
        v = previous + _clamp(v - previous, accel_low * dt, accel_high * dt)
    v = _clamp(v, low, high)
    # Only commands near float's end overflow here (1e308 m/s): nothing to follow, a stop.
    return v if math.isfinite(v) else 0.0


def _clamp(value: float, low: float, high: float) -> float:
    return min(max(value, low), high)


def velocity_scale(v: float, omega: float, linear: AxisLimits, angular: AxisLimits) -> float:
    """The factor (0 to 1) that brings both ``v`` and ``omega`` within their velocity
    limits together, keeping the command's curvature (as :func:`~fpgalink.robot.drive.
    wheel_command` scales for the robot's own limits); 1.0 for non-finite input."""
    scale = 1.0
    for value, limits in ((v, linear), (omega, angular)):
        low, high = limits.velocity_bounds()
        if not math.isfinite(value):
            return 1.0
        if value > high:
            scale = min(scale, high / value)
        elif value < low:
            scale = min(scale, low / value)
    return scale if scale > 0 else 0.0


class SpeedLimiter:
    """Both axes of a body command, with the two commands given before (the limiter's
    memory): :meth:`step` once per control period, :meth:`follow` when what was driven
    differs from what the limiter gave (another source drove, the robot stopped, the
    robot's own limits scaled it)."""

    def __init__(self, linear: AxisLimits | None = None,
                 angular: AxisLimits | None = None) -> None:
        self.linear = linear or AxisLimits()
        self.angular = angular or AxisLimits()
        #: (v, ω) one step ago and two steps ago
        self._history = ((0.0, 0.0), (0.0, 0.0))

    @property
    def rate_limited(self) -> bool:
        return self.linear.rate_limited or self.angular.rate_limited

    @property
    def last(self) -> tuple[float, float]:
        return self._history[0]

    def reset(self, v: float = 0.0, omega: float = 0.0) -> None:
        """Start again from (``v``, ``omega``), as if held for two steps (non-finite: 0)."""
        now = (v if math.isfinite(v) else 0.0, omega if math.isfinite(omega) else 0.0)
        self._history = (now, now)

    def follow(self, v: float, omega: float) -> None:
        """What was driven in place of the last step's output (non-finite: 0)."""
        now = (v if math.isfinite(v) else 0.0, omega if math.isfinite(omega) else 0.0)
        self._history = (now, self._history[1])

    def target(self, v: float, omega: float) -> tuple[float, float]:
        """``(v, omega)`` scaled into the velocity limits keeping its curvature; (0, 0)
        when either is not finite."""
        if not (math.isfinite(v) and math.isfinite(omega)):
            return 0.0, 0.0
        scale = velocity_scale(v, omega, self.linear, self.angular)
        # Clamped as well: v · (high / v) may round just past high.
        return (_clamp(v * scale, *self.linear.velocity_bounds()),
                _clamp(omega * scale, *self.angular.velocity_bounds()))

    def step(self, v: float, omega: float, dt: float) -> tuple[float, float]:
        """The command for this period towards (``v``, ``omega``) (see :meth:`target`)
        after ``dt`` s, remembered as the latest."""
        v, omega = self.target(v, omega)
        (v0, omega0), (v1, omega1) = self._history
        if not (math.isfinite(dt) and dt > 0):
            return v0, omega0
        out = (limit_axis(v, v0, v1, dt, self.linear),
               limit_axis(omega, omega0, omega1, dt, self.angular))
        self._history = (out, (v0, omega0))
        return out
