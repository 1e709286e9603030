"""A live view of the boards and the robot for Foxglove (``--foxglove [HOST:]PORT``): a
``foxglove.websocket.v1`` server, from the maintained foxglove-sdk (the ``foxglove`` extra),
streaming what a recording holds, as it happens. A layer above the robot, beside the CLI:
the CLI and the ROS 2 node open one; the robot never imports it. See docs/live.md.

    view = LiveView(parse_address("8765"), "fpgalink-cli drive")
    view.start()                       # listening: view.url
    view.add_board("L", tap)           # per board: telemetry, parameters, events, stats
    view.add_robot(robot, truth)       # pose, path, truth, /tf, URDF, supervision
    ...
    await view.close()
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from fpgalink.live.address import DEFAULT_PORT, LiveAddress, parse_address
from fpgalink.live.feeds import BoardFeed, BoardTap, RobotFeed
from fpgalink.live.server import INSTALL_HINT, LiveServer, LiveStats, require_sdk

if TYPE_CHECKING:
    from fpgalink.robot.robot import Robot

__all__ = ["DEFAULT_PORT", "INSTALL_HINT", "BoardTap", "LiveAddress", "LiveStats", "LiveView",
           "parse_address", "require_sdk"]


class LiveView:
    """One live view: its server and what it shows. ``start`` inside the event loop that
    runs the links; ``close`` before the loop ends."""

    def __init__(self, address: LiveAddress, name: str,
                 say: Callable[[str], None] = lambda text: None) -> None:
        self.server = LiveServer(address, name, say)
        self._boards: list[BoardFeed] = []
        self._robot: RobotFeed | None = None

    @property
    def url(self) -> str:
        return self.server.url

    @property
    def stats(self) -> LiveStats:
        return self.server.stats

    def start(self) -> None:
        self.server.start()

    def add_board(self, name: str, tap: BoardTap) -> None:
        feed = BoardFeed(self.server, name, tap)
        feed.start()
        self._boards.append(feed)

    def add_robot(self, robot: Robot,
                  truth: Callable[[], dict[str, Any] | None] | None = None) -> None:
        """The robot, and each of its boards."""
        for name in robot.description.boards:
            self.add_board(name, BoardTap.of_robot(robot, name))
        self._robot = RobotFeed(self.server, robot, truth)
        self._robot.start()

    async def close(self) -> None:
        for feed in self._boards:
            await feed.close()
        if self._robot is not None:
            await self._robot.close()
        self.server.stop()
