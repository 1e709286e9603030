"""Body commands to wheel references: the seed's TelepoController (both wheels of a side get
the same reference), with limits that keep the commanded curvature."""

from __future__ import annotations

import math
from dataclasses import dataclass

from fpgalink.protocol import LocalProtocolError
from fpgalink.protocol.robot import RobotDescription, SkidSteer

__all__ = ["WheelCommand", "changed_kinematics", "wheel_command"]


@dataclass(frozen=True, slots=True)
class WheelCommand:
    """What the boards are told, and what was asked."""

    v: float  #: m/s, after limits
    omega: float  #: rad/s, after limits
    left_dps: float  #: wheel speed of the left side, deg/s, positive forward
    right_dps: float
    scale: float  #: 1.0, or the factor both v and ω were scaled by to respect a limit
    #: board → (ref A, ref B), deg/s in each board's own sign convention
    references: dict[str, tuple[float, float]]


def wheel_command(description: RobotDescription, v: float, omega: float,
                  kinematics: SkidSteer | None = None) -> WheelCommand:
    """Wheel references for body speed ``v`` (m/s) and yaw rate ``omega`` (rad/s).

    When a limit would be exceeded — the robot's speed or turn rate, or any wheel's
    maximum speed — v and ω are scaled by the same factor, so the robot follows the same
    arc, only slower. Non-finite values raise
    :class:`~fpgalink.protocol.LocalProtocolError` and nothing is computed."""
    if not (math.isfinite(v) and math.isfinite(omega)):
        raise LocalProtocolError(f"a body command must be finite numbers, got v={v!r}, "
                                 f"omega={omega!r}")
    model = kinematics or description.kinematics()
    scale = 1.0
    if abs(v) > description.max_linear_speed:
        scale = min(scale, description.max_linear_speed / abs(v))
    if abs(omega) > description.max_angular_speed_rad:
        scale = min(scale, description.max_angular_speed_rad / abs(omega))
    left, right = model.wheel_speeds(v * scale, omega * scale)
    fastest = max(abs(left), abs(right))
    if fastest > description.max_wheel_speed:
        wheel_scale = description.max_wheel_speed / fastest
        scale *= wheel_scale
        left, right = left * wheel_scale, right * wheel_scale
    references: dict[str, list[float]] = {b: [0.0, 0.0] for b in description.boards}
    for wheel in description.wheels:
        side = left if wheel.left else right
        references[wheel.board][wheel.channel - 1] = side * wheel.forward
    return WheelCommand(v * scale, omega * scale, left, right, scale,
                        {b: (a, bb) for b, (a, bb) in references.items()})


def changed_kinematics(model: SkidSteer, *, wheel_radius: float | None = None,
                       track: float | None = None, chi: float | None = None,
                       left_radius_multiplier: float | None = None,
                       right_radius_multiplier: float | None = None) -> SkidSteer:
    """``model`` with the values given changed, the others kept. ``ValueError`` for a value
    that is not finite and positive (χ: ≥ 1)."""
    wanted = {"wheel_radius": (model.wheel_radius if wheel_radius is None else wheel_radius,
                               0.0),
              "track": (model.track if track is None else track, 0.0),
              "chi": (model.chi if chi is None else chi, 1.0),
              "left_radius_multiplier": (model.left_radius_multiplier
                                         if left_radius_multiplier is None
                                         else left_radius_multiplier, 0.0),
              "right_radius_multiplier": (model.right_radius_multiplier
                                          if right_radius_multiplier is None
                                          else right_radius_multiplier, 0.0)}
    for name, (value, low) in wanted.items():
        if not (math.isfinite(value) and (value > low if low == 0.0 else value >= low)):
            raise ValueError(f"{name} must be a finite number "
                             f"{'> 0' if low == 0.0 else '≥ 1'}, got {value!r}")
    return SkidSteer(*(value for value, _ in wanted.values()))
