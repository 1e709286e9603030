"""The robot's errors (re-exported by :mod:`fpgalink.robot.robot` and :mod:`fpgalink.robot`)."""

from __future__ import annotations

from fpgalink.errors import FpgalinkError
from fpgalink.robot.supervision import SupervisionEvent

__all__ = ["GoalTimeout", "RobotClosed", "RobotError", "RobotStopped"]


class RobotError(FpgalinkError):
    """The robot cannot do what was asked (not started, a board missing, bad settings)."""


class RobotStopped(RobotError):
    """Supervision stopped the robot (``event`` says why), or it was not enabled."""

    def __init__(self, message: str, event: SupervisionEvent | None = None) -> None:
        super().__init__(message)
        self.event = event


class RobotClosed(RobotError):
    """The robot was closed: every command after :meth:`~fpgalink.robot.Robot.close`
    raises this, as a closed :class:`~fpgalink.aio.Link`'s raise
    :class:`~fpgalink.errors.LinkClosed`."""


class GoalTimeout(RobotError):
    """``go_to`` did not arrive in time; the robot was stopped."""
