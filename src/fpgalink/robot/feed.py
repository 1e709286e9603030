"""What the robot hands its readers as they come (supervision events, stamped sample sets):
the link's bounded :class:`~fpgalink.aio.link.Subscription` (``async for``, its oldest item
dropped and counted when full, ended when the robot closes or the reader closes it), with
the writer's side public: the robot is another object than the link."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from fpgalink.aio.link import Subscription
from fpgalink.robot.stamping import SampleStamper, StampedSet

__all__ = ["Feed", "SetFeed"]

T = TypeVar("T")


class Feed(Subscription[T]):
    def put(self, item: T) -> None:
        """Queue ``item`` (the writer's side)."""
        self._push(item)

    def end(self) -> None:
        """No more items (the writer's side): the reader's loop ends once it has read
        what is queued."""
        self._end()


class SetFeed(Feed[StampedSet]):
    """A reader's stamped sample sets (:meth:`fpgalink.robot.Robot.sample_sets`)."""

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
