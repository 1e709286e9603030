"""What waits for one board's line, paced and bounded by line time (sans-I/O: time passed
in)."""

from __future__ import annotations

import math
from collections import deque
from typing import Generic, TypeVar

__all__ = ["BOARD_QUEUE_S", "LINE_LEAD_S", "LineQueue"]

T = TypeVar("T")

#: At most this much line time waits for a board (handed to its port and not yet on the
#: wire, or queued here): 20,000 bytes at 1 MBd. A controller writing faster than the line
#: carries has the excess refused and counted, and its RD (or the router's, when it leaves)
#: is never more than this behind.
BOARD_QUEUE_S = 0.2
#: The controller's frames are handed to the port while what was handed before has less
#: than this much line time left to go: the line never idles for want of a frame, and what
#: the port's driver holds (which nothing can overtake) stays this short.
LINE_LEAD_S = 0.02


class LineQueue(Generic[T]):
    """What waits for one board's line, paced by line time (sans-I/O: time passed in).

    :meth:`push` queues a frame (O(1)), or refuses it when :data:`BOARD_QUEUE_S` of line
    time would then wait in all — queued here, or handed out and not yet on the wire.
    :meth:`take` hands out, in order, what may go to the port now: frames while what was
    handed before has less than :data:`LINE_LEAD_S` left to go. :meth:`wake_at` says when
    to take again. :meth:`overtake` puts a frame (``RD``) ahead of everything waiting, which
    is dropped and returned: nothing queued before a disable may follow it."""

    def __init__(self, baud: int, bound: float = BOARD_QUEUE_S, lead: float = LINE_LEAD_S
                 ) -> None:
        self.byte_time = 10 / baud  #: 8N1: ten bit times a byte
        self.bound = bound
        self.lead = lead
        self._waiting: deque[tuple[T, int]] = deque()
        self._waiting_bytes = 0
        self._free_at = -math.inf  #: when what was handed out will have left the line

    def __len__(self) -> int:
        return len(self._waiting)

    def in_flight(self, now: float) -> float:
        """Line time still to go of what was handed out, s."""
        return max(0.0, self._free_at - now)

    def backlog(self, now: float) -> float:
        """Line time of everything not yet on the wire, handed out or waiting, s."""
        return self.in_flight(now) + self._waiting_bytes * self.byte_time

    def room(self, now: float) -> int:
        """Wire bytes that may still be pushed now."""
        return max(0, int((self.bound - self.backlog(now)) / self.byte_time + 1e-6))

    def full(self, size: int, now: float) -> bool:
        """Whether a frame of ``size`` wire bytes would take the backlog past the bound."""
        # (A nanosecond's slack: a bound filled exactly is not exceeded by rounding.)
        return self.backlog(now) + size * self.byte_time > self.bound + 1e-9

    def push(self, item: T, size: int, now: float) -> bool:
        """Queue ``item`` (``size`` wire bytes); ``False``: refused, the line is full."""
        if self.full(size, now):
            return False
        self._waiting.append((item, size))
        self._waiting_bytes += size
        return True

    def take(self, now: float) -> list[T]:
        """What goes to the port now, in order."""
        out: list[T] = []
        waiting = self._waiting
        free = max(self._free_at, now)
        while waiting and free - now < self.lead:
            item, size = waiting.popleft()
            self._waiting_bytes -= size
            free += size * self.byte_time
            out.append(item)
        if out:
            self._free_at = free
        return out

    def wake_at(self) -> float | None:
        """When :meth:`take` has something again (``None``: nothing waits)."""
        return self._free_at - self.lead / 2 if self._waiting else None

    def overtake(self, size: int, now: float) -> list[T]:
        """A frame of ``size`` bytes goes to the port now, ahead of everything waiting;
        returns what waited, dropped."""
        dropped = self.clear()
        self._free_at = max(self._free_at, now) + size * self.byte_time
        return dropped

    def clear(self) -> list[T]:
        """Drop everything waiting (returned, oldest first)."""
        dropped = [item for item, _ in self._waiting]
        self._waiting.clear()
        self._waiting_bytes = 0
        return dropped

    def reset(self) -> list[T]:
        """A new port (the old one went away): nothing is on its line; what waited is
        dropped and returned."""
        self._free_at = -math.inf
        return self.clear()
