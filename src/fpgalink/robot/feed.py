"""What the robot hands its readers as they come (supervision events, stamped sample sets):
the link's bounded :class:`~fpgalink.aio.link.Subscription` (``async for``, its oldest item
dropped and counted when full, ended when the robot closes or the reader closes it), with
the writer's side public: the robot is another object than the link."""

from __future__ import annotations

from typing import TypeVar

from fpgalink.aio.link import Subscription

__all__ = ["Feed"]

T = TypeVar("T")


class Feed(Subscription[T]):
    def put(self, item: T) -> None:
        """Queue ``item`` (the writer's side)."""
        self._push(item)

    def end(self) -> None:
        """No more items (the writer's side): the reader's loop ends once it has read
        what is queued."""
        self._end()
