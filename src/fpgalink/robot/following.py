"""The robot following its boards' telemetry: a task a board, each sample handed to the
tracking (odometry, latest samples, readers) and, on the first board's, to the command
arbiter's control step; and a read of the present (the links' batches ended at once, the
followers given their turn), for links that read in batches (docs/robot.md)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from contextlib import AbstractContextManager

from fpgalink.aio.link import Link, Stamped, Subscription
from fpgalink.protocol import Telemetry
from fpgalink.robot.arbiter import CommandArbiter
from fpgalink.robot.boards import Boards
from fpgalink.robot.tracking import Tracking

__all__ = ["TelemetryFollowers"]

#: Samples a board's follower may hold unread (a batch of reads is far fewer).
FOLLOW_QUEUE = 4096


class TelemetryFollowers:
    """``guarded(what)``: the robot's guard, under which each follower runs (an exception
    stops the robot, said)."""

    def __init__(self, boards: Boards, tracking: Tracking, arbiter: CommandArbiter,
                 lead: str, guarded: Callable[[str], AbstractContextManager[None]]) -> None:
        self._boards, self._tracking, self._arbiter = boards, tracking, arbiter
        self._lead, self._guarded = lead, guarded
        self._following: list[tuple[Subscription[Stamped], asyncio.Task[None]]] = []

    def follow(self, name: str, link: Link) -> asyncio.Task[None]:
        """Follow board ``name``'s telemetry from now on (the task is the caller's to end)."""
        samples = link.stamped_telemetry(maxsize=FOLLOW_QUEUE)
        task = asyncio.ensure_future(self._follow(name, samples))
        self._following.append((samples, task))
        return task

    async def read_now(self) -> None:
        """Take at once what the boards have sent, and return when the followers have."""
        for link in self._boards.links.values():
            link.read_now()
        # Each follower takes what was queued at its next turn (the links queue no more
        # meanwhile: they were read up to now).
        while any(len(samples) and not task.done() for samples, task in self._following):
            await asyncio.sleep(0)

    async def _follow(self, name: str, samples: Subscription[Stamped]) -> None:
        with self._guarded(f"board {name}'s telemetry (odometry)"):
            async for received, sample in samples:
                self._on_sample(name, received, sample)

    def _on_sample(self, name: str, received: float, sample: Telemetry) -> None:
        """One board's sample: tracked, and on the lead board's the control step."""
        self._tracking.add(name, received, sample)
        if name == self._lead:
            send = self._arbiter.control_step(sample.t_us)
            if send is not None and send.command is not None:
                self._boards.send_each(send.references)
                self._tracking.drove(sample.t_us, send.command)
        self._tracking.publish(name, received, sample)
