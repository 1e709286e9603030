"""The robot: two boards as one skid-steered base (seed §2.6, §3.3, §3.5).

* the description and the skid-steer model, shared with the emulator, live in
  :mod:`fpgalink.protocol.robot` (re-exported here);
* :mod:`.drive` — body command → wheel references, limits keeping the curvature;
* :mod:`.arbiter` — what drives the wheels now (body commands, wheel references, velocity
  commands under limits, timed and held commands, the enable's renewal);
* :mod:`.stamping` — the boards' samples as sets stamped on a reader's clock;
* :mod:`.limits` — diff_drive_controller's velocity, acceleration and jerk limits;
* :mod:`.odometry` — pose from encoder counts, with a covariance;
* :mod:`.supervision` — the deadman and the boards' liveness, as a table;
* :mod:`.goto` — the seed's position controller (Algorithm 1);
* :mod:`.robot` — :class:`Robot`, all of it over one asyncio link per board.

Everything but :class:`Robot` and what it runs over the links is sans-I/O: time is passed
in. Names load on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fpgalink.protocol.exports import lazy_exports

_HOMES = {
    "DescriptionError": "fpgalink.protocol.robot",
    "Pose": "fpgalink.protocol.robot",
    "RobotDescription": "fpgalink.protocol.robot",
    "SkidSteer": "fpgalink.protocol.robot",
    "load_robot": "fpgalink.protocol.robot",
    "parse_robot": "fpgalink.protocol.robot",
    "seed_robot": "fpgalink.protocol.robot",
    "WheelCommand": "fpgalink.robot.drive",
    "CommandArbiter": "fpgalink.robot.arbiter",
    "CommandNotice": "fpgalink.robot.arbiter",
    "Commanded": "fpgalink.robot.arbiter",
    "BoardNotice": "fpgalink.robot.recovery",
    "StampedSet": "fpgalink.robot.stamping",
    "wheel_command": "fpgalink.robot.drive",
    "AxisLimits": "fpgalink.robot.limits",
    "SpeedLimiter": "fpgalink.robot.limits",
    "Odometry": "fpgalink.robot.odometry",
    "OdometryState": "fpgalink.robot.odometry",
    "NotReady": "fpgalink.robot.supervision",
    "StopReason": "fpgalink.robot.supervision",
    "SupervisionEvent": "fpgalink.robot.supervision",
    "Supervisor": "fpgalink.robot.supervision",
    "GoTo": "fpgalink.robot.goto",
    "GoToSettings": "fpgalink.robot.goto",
    "Phase": "fpgalink.robot.goto",
    "GoalTimeout": "fpgalink.robot.robot",
    "Robot": "fpgalink.robot.robot",
    "RobotClosed": "fpgalink.robot.robot",
    "RobotError": "fpgalink.robot.robot",
    "RobotStopped": "fpgalink.robot.robot",
}

if TYPE_CHECKING:
    from fpgalink.protocol.robot import (
        DescriptionError,
        Pose,
        RobotDescription,
        SkidSteer,
        load_robot,
        parse_robot,
        seed_robot,
    )
    from fpgalink.robot.arbiter import CommandArbiter, Commanded, CommandNotice
    from fpgalink.robot.drive import WheelCommand, wheel_command
    from fpgalink.robot.goto import GoTo, GoToSettings, Phase
    from fpgalink.robot.limits import AxisLimits, SpeedLimiter
    from fpgalink.robot.odometry import Odometry, OdometryState
    from fpgalink.robot.recovery import BoardNotice
    from fpgalink.robot.robot import GoalTimeout, Robot, RobotClosed, RobotError, RobotStopped
    from fpgalink.robot.stamping import StampedSet
    from fpgalink.robot.supervision import NotReady, StopReason, SupervisionEvent, Supervisor


__getattr__ = lazy_exports(__name__, _HOMES)

__all__ = [
    "AxisLimits",
    "BoardNotice",
    "CommandArbiter",
    "CommandNotice",
    "Commanded",
    "DescriptionError",
    "GoTo",
    "GoToSettings",
    "GoalTimeout",
    "NotReady",
    "Odometry",
    "OdometryState",
    "Phase",
    "Pose",
    "Robot",
    "RobotClosed",
    "RobotDescription",
    "RobotError",
    "RobotStopped",
    "SkidSteer",
    "SpeedLimiter",
    "StampedSet",
    "StopReason",
    "SupervisionEvent",
    "Supervisor",
    "WheelCommand",
    "load_robot",
    "parse_robot",
    "seed_robot",
    "wheel_command",
]
