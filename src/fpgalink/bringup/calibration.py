"""Odometry against a reference: the skid-steer's effective track (χ) from a turn in place
and the wheel radius from a straight run.

Odometry turns the wheels' motion into the body's by the robot file's model
(:mod:`fpgalink.protocol.robot`): a side's way is ``r·φ`` (wheel radius r, wheel angle φ)
and the body turns by ``(s_R − s_L)/(χ·B)``. So for the same wheel motion

* the angle odometry says is proportional to ``1/χ``: with χ₀ in use, odometry's angle
  α₀ and the reference's α, the χ that makes them agree is ``χ₀·α₀/α``;
* the way it says is proportional to ``r``: ``r = r₀·d/d₀``.

The reference is the user's own measurement (an angle read off marks on the floor, a
distance taped out), an IMU's yaw rate integrated (:class:`GyroHeading`, its bias measured
while the robot stands still first), or an emulated robot's truth. χ belongs to the surface
(docs/robot.md): calibrate on each one the robot drives on. Sans-I/O.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

__all__ = [
    "MIN_DISTANCE",
    "MIN_TURN",
    "CalibrationError",
    "GyroHeading",
    "Motion",
    "Result",
    "Sample",
    "chi_from_turn",
    "motion_of",
    "radius_from_run",
    "unwrapped_change",
]

#: The shortest turn (rad) and way (m) a calibration is taken from: shorter, the
#: reference's own error (a degree of reading, a centimetre of tape) is too large a share.
MIN_TURN = math.radians(90.0)
MIN_DISTANCE = 0.5
#: The robot file's bounds (fpgalink.protocol.robot).
CHI_RANGE = (1.0, 10.0)
RADIUS_RANGE = (0.01, 10.0)


class CalibrationError(ValueError):
    """The run cannot calibrate (too short, the reference and odometry disagree in sign, a
    result outside what a robot file accepts); the message says why."""


@dataclass(frozen=True, slots=True)
class Result:
    """One calibrated quantity: before and after, and what they came from."""

    name: str  #: "chi" or "wheel_radius"
    before: float
    after: float
    odometry: float  #: rad or m, as odometry measured it with ``before``
    reference: float  #: rad or m, the reference's

    @property
    def error_before(self) -> float:
        """Odometry's error with ``before``, as a share of the reference."""
        return (self.odometry - self.reference) / self.reference


def _checked(name: str, value: float, bounds: tuple[float, float], why: str) -> float:
    low, high = bounds
    if not (math.isfinite(value) and low <= value <= high):
        raise CalibrationError(f"{name} would be {value:.4g}, outside {low:g}..{high:g} "
                               f"{why}")
    return value


def _finite(what: str, odometry: float, reference: float) -> None:
    for name, value in ((f"odometry's {what}", odometry), (f"the reference's {what}",
                                                             reference)):
        if not math.isfinite(value):
            raise CalibrationError(f"{name} is not a number")


def chi_from_turn(chi: float, odometry_turn: float, reference_turn: float) -> Result:
    """χ from a turn in place: odometry said ``odometry_turn`` rad with ``chi``, the
    reference ``reference_turn`` rad (both signed, counter-clockwise positive)."""
    _finite("turn", odometry_turn, reference_turn)
    if abs(reference_turn) < MIN_TURN:
        raise CalibrationError(f"the reference turned {math.degrees(reference_turn):.1f}°: at "
                               f"least {math.degrees(MIN_TURN):.0f}° is needed")
    if odometry_turn * reference_turn <= 0:
        raise CalibrationError(f"odometry turned {math.degrees(odometry_turn):.1f}° and the "
                               f"reference {math.degrees(reference_turn):.1f}°: opposite ways "
                               "(a wheel's forward sign or the reference's axis is wrong)")
    after = _checked("χ", chi * odometry_turn / reference_turn, CHI_RANGE,
                     "(odometry and the reference are too far apart: a wheel slipping on a "
                     "stop, the wrong surface, a reference of another run?)")
    return Result("chi", chi, after, odometry_turn, reference_turn)


def radius_from_run(radius: float, odometry_distance: float, reference_distance: float
                    ) -> Result:
    """The wheel radius from a straight run: odometry said ``odometry_distance`` m with
    ``radius``, the reference ``reference_distance`` m (signed: backwards negative)."""
    _finite("distance", odometry_distance, reference_distance)
    if abs(reference_distance) < MIN_DISTANCE:
        raise CalibrationError(f"the reference says {reference_distance:.3f} m: at least "
                               f"{MIN_DISTANCE:g} m is needed")
    if odometry_distance * reference_distance <= 0:
        raise CalibrationError(f"odometry went {odometry_distance:.3f} m and the reference "
                               f"{reference_distance:.3f} m: opposite ways")
    after = _checked("the wheel radius", radius * reference_distance / odometry_distance,
                     RADIUS_RANGE, "m")
    return Result("wheel_radius", radius, after, odometry_distance, reference_distance)


def unwrapped_change(angles: Iterable[float]) -> float:
    """The total signed change of a sequence of headings (rad, wrapped to ±π), following
    every turn through ±π: sampled at least every half turn."""
    total = 0.0
    last: float | None = None
    for angle in angles:
        if not math.isfinite(angle):
            continue
        if last is not None:
            total += math.remainder(angle - last, math.tau)
        last = angle
    return total


class GyroHeading:
    """A heading from a gyro's yaw rate: the bias is the mean rate while the robot stands
    still (:meth:`still`), then (rate − bias) is integrated over time (trapezoids) while it
    turns (:meth:`turning`). Samples are (time s, yaw rate rad/s)."""

    def __init__(self) -> None:
        self._still: list[float] = []
        self._last: tuple[float, float] | None = None
        self.heading = 0.0  #: rad turned since the first turning sample
        self.samples = 0

    @property
    def bias(self) -> float:
        return sum(self._still) / len(self._still) if self._still else 0.0

    def still(self, rate: float) -> None:
        if math.isfinite(rate):
            self._still.append(rate)

    def turning(self, t: float, rate: float) -> None:
        if not (math.isfinite(t) and math.isfinite(rate)):
            return
        rate -= self.bias
        if self._last is not None and t > self._last[0]:
            self.heading += 0.5 * (rate + self._last[1]) * (t - self._last[0])
        self._last = (t, rate)
        self.samples += 1

    @classmethod
    def from_samples(cls, still: Sequence[float], turning: Sequence[tuple[float, float]]
                     ) -> GyroHeading:
        gyro = cls()
        for rate in still:
            gyro.still(rate)
        for t, rate in turning:
            gyro.turning(t, rate)
        return gyro


@dataclass(frozen=True, slots=True)
class Sample:
    """The robot at one moment of a calibration run."""

    t: float  #: s, host time
    phase: str  #: "still", "moving" or "settling", with the motion's name: "turn-moving"
    odometry: tuple[float, float, float]  #: x m, y m, θ rad
    truth: tuple[float, float, float] | None = None  #: an emulated robot's true pose
    gyro: tuple[float, float] | None = None  #: (time s, yaw rate rad/s) of an IMU reading


@dataclass(frozen=True, slots=True)
class Motion:
    """What odometry and each reference measured over one motion (from rest to rest)."""

    name: str  #: "turn" or "straight"
    odometry_turn: float  #: rad
    odometry_distance: float  #: m, along the starting heading (signed)
    truth_turn: float | None
    truth_distance: float | None
    gyro_turn: float | None  #: rad, the gyro's rate less its bias while still, integrated
    seconds: float


def _along(poses: list[tuple[float, float, float]]) -> float:
    (x0, y0, heading), (x1, y1, _) = poses[0], poses[-1]
    return (x1 - x0) * math.cos(heading) + (y1 - y0) * math.sin(heading)


def motion_of(samples: Sequence[Sample], name: str) -> Motion:
    """The ``name`` motion of a run: from its last still sample to its last settling one
    (both at rest)."""
    still = [s for s in samples if s.phase == f"{name}-still"]
    moving = [s for s in samples if s.phase in (f"{name}-moving", f"{name}-settling")]
    if not still or not moving:
        raise CalibrationError(f"the run has no {name}")
    span = [still[-1], *moving]
    odometry = [s.odometry for s in span]
    truths = [s.truth for s in span]
    truth_turn = truth_distance = None
    if all(t is not None for t in truths):
        poses = [t for t in truths if t is not None]
        truth_turn = unwrapped_change(p[2] for p in poses)
        truth_distance = _along(poses)
    gyro_turn = None
    readings = [s.gyro for s in samples if s.gyro is not None]
    if readings and any(s.gyro is not None for s in moving):
        heading = GyroHeading()
        for s in still:
            if s.gyro is not None:
                heading.still(s.gyro[1])
        seen: set[float] = set()
        for s in span:
            if s.gyro is not None and s.gyro[0] not in seen:
                seen.add(s.gyro[0])
                heading.turning(*s.gyro)
        gyro_turn = heading.heading
    return Motion(name, unwrapped_change(p[2] for p in odometry), _along(odometry),
                  truth_turn, truth_distance, gyro_turn, span[-1].t - span[0].t)
