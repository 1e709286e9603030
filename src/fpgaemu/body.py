"""The robot's body: one rigid body in the plane that the four emulated wheels move (the
physical world above the wheels, as :mod:`fpgaemu.motor` is the world below the boards).

Each wheel's rotation comes from its motor plant (the exact integral of its speed); a side
rolls the mean of its two wheels' ground distance, and the body moves through the same
skid-steer model the host uses (:class:`fpgalink.protocol.robot.SkidSteer`), with the χ of
the surface it stands on. The body's pose is the truth odometry is measured against.
Simplifications: the ground does not load the wheels (their plants run as identified), and
the two wheels of a side agree (their mean moves the side).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from fpgalink.protocol.robot import (
    LEFT_WHEELS,
    RIGHT_WHEELS,
    Pose,
    RobotDescription,
    integrate_arc,
)

__all__ = ["Body", "BodyState"]


@dataclass(frozen=True, slots=True)
class BodyState:
    """The body's true state at one moment."""

    t: float  #: s of emulated time
    pose: Pose
    v: float  #: m/s over the last step
    omega: float  #: rad/s over the last step
    distance: float  #: m travelled
    surface: str
    #: which body: ``kinematic`` (this module) or ``mujoco`` (:mod:`fpgaemu.physics`)
    body: str = "kinematic"
    z: float = 0.0  #: m, base_link's height (a physics body; 0 for the planar one)
    roll: float = 0.0  #: rad
    pitch: float = 0.0  #: rad, positive nose down (REP-103)
    #: the IMU's reading (a physics body's): :class:`fpgaemu.physics.ImuReading`
    imu: Any = None

    def record(self) -> dict[str, Any]:
        """The state as the truth stream's JSON record (docs/emulator.md §17)."""
        record: dict[str, Any] = {
            "t": self.t, "x": self.pose.x, "y": self.pose.y, "theta": self.pose.theta,
            "v": self.v, "omega": self.omega, "distance": self.distance,
            "surface": self.surface, "body": self.body}
        if self.body != "kinematic":
            record.update(z=self.z, roll=self.roll, pitch=self.pitch)
        if self.imu is not None:
            record["imu"] = self.imu.record()
        return record


class Body:
    """``follow(t, angles)`` with each wheel's physical angle (deg) moves the body; read
    :attr:`pose` and :meth:`state`."""

    def __init__(self, description: RobotDescription, surface: str | None = None,
                 pose: Pose | None = None) -> None:
        self.surface = surface or description.surface
        self.kinematics = description.kinematics(self.surface)
        self.radius = description.wheel_radius
        # The sign of physical rotation that moves the robot forward: the board's speed is
        # physical × its count direction, and the description says which board sign is
        # forward. Fixed when the robot is built, as the wiring is.
        self.mount: dict[str, int] = {}
        for wheel in description.wheels:
            direction = 1
            for param, channel, value in description.settings_for(wheel.board):
                if param.name == "IncSenzCountDirection" and channel == wheel.channel:
                    direction = int(value)
            self.mount[wheel.name] = wheel.forward * direction
        self.pose = pose or Pose()
        self.t = 0.0
        self.v = 0.0
        self.omega = 0.0
        self.distance = 0.0
        self.steps = 0  #: times the body has followed the wheels
        self._angles: dict[str, float] | None = None

    def follow(self, t: float, angles: Mapping[str, float]) -> None:
        """The wheels stand at ``angles`` (deg, physical) at emulated time ``t`` (s)."""
        self.steps += 1
        last, self._angles = self._angles, dict(angles)
        dt, self.t = t - self.t, t
        if last is None:
            return
        radius, mount, radians = self.radius, self.mount, math.radians
        # Each side's mean arc, summed from 0.0 in wheel order.
        left = 0.0
        for n in LEFT_WHEELS:
            left += radians(angles[n] - last[n]) * radius * mount[n]
        left /= len(LEFT_WHEELS)
        right = 0.0
        for n in RIGHT_WHEELS:
            right += radians(angles[n] - last[n]) * radius * mount[n]
        right /= len(RIGHT_WHEELS)
        distance, turn = self.kinematics.displacement(left, right)
        self.pose = integrate_arc(self.pose, distance, turn)
        self.distance += abs(distance)
        if dt > 0:
            self.v, self.omega = distance / dt, turn / dt

    def state(self) -> BodyState:
        return BodyState(self.t, self.pose, self.v, self.omega, self.distance, self.surface)
