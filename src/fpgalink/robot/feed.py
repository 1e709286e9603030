"""What the robot hands its readers as they come (supervision events, stamped sample sets):
the bounded :class:`~fpgalink.aio.subscription.Subscription` (``async for``, its oldest item
dropped and counted when full, ended when the robot closes or the reader closes it), whose
producer's side (``put``/``finish``) is public: the robot is another object than the link."""

from __future__ import annotations

from collections.abc import Callable

from fpgalink.aio.subscription import Subscription
from fpgalink.robot.stamping import SampleStamper, StampedSet

__all__ = ["SetFeed"]


class SetFeed(Subscription[StampedSet]):
    """A reader's stamped sample sets (:meth:`fpgalink.robot.Robot.sample_sets`), each made
    by its own :class:`~fpgalink.robot.stamping.SampleStamper`."""

    def __init__(self, maxsize: int, on_close: Callable[[Subscription[StampedSet]], None],
                 stamper: SampleStamper) -> None:
        super().__init__(maxsize, on_close)
        self.stamper = stamper

    @property
    def min_period(self) -> float:
        """At most one set per this many seconds (of arrival time)."""
        return self.stamper.min_period

    @min_period.setter
    def min_period(self, seconds: float) -> None:
        self.stamper.min_period = seconds
