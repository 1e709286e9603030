"""``fpgalink-ros2 --bag DIR``: the node's own inputs (as received) and outputs (as
published) into a rosbag2 — version 9, MCAP storage, CDR — written with ``rosbags`` (no
``ros2 bag`` needed), so a run can be replayed with ``ros2 bag play`` or read with
Foxglove, PlotJuggler or ``rosbags``.

Each message is serialised by rclpy exactly as it went over DDS and written under its
resolved topic name (``/bot/odom`` in a namespace); its bag time is the node's clock when
it was published or handed to the node (the ROS clock: /clock time under
``use_sim_time``), as ``ros2 bag record`` stamps what it receives. Every write happens on
the asyncio thread (subscriptions hand their messages there first), so the writer needs no
lock. A write that fails (a full disk) ends the recording with one error and closes the
bag; the node goes on.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

__all__ = ["BagError", "NodeBag"]


class BagError(Exception):
    """The bag cannot be made: one line saying why."""


class NodeBag:
    """One bag for one run of the node."""

    def __init__(self, path: Path, metadata: dict[str, str]) -> None:
        try:
            from rosbags.rosbag2 import StoragePlugin, Writer
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise BagError("--bag needs the rosbags library: pip install 'fpgalink[ros2]'"
                           ) from None
        if path.exists():
            raise BagError(f"--bag {path}: already exists (a bag is a new directory)")
        if not path.parent.is_dir():
            raise BagError(f"--bag {path}: no such directory {path.parent}")
        self.path = path
        self.messages = 0
        self.failed: str | None = None
        self._types = get_typestore(Stores.ROS2_JAZZY)
        self._writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        for key, value in metadata.items():
            self._writer.set_custom_data(f"fpgalink.{key}", value)
        try:
            self._writer.open()
        except OSError as exc:
            raise BagError(f"--bag {path}: cannot write: {exc.strerror or exc}") from None
        self._connections: dict[str, Any] = {}
        self._closed = False

    def write(self, topic: str, message: Any, log_ns: int) -> str | None:
        """``message`` (an rclpy message) on ``topic``; returns why the recording just
        stopped, once, or ``None``."""
        if self._closed:
            return None
        from rclpy.serialization import serialize_message

        msgtype = _msgtype(message)
        try:
            connection = self._connections.get(topic)
            if connection is None:
                # On first use: the topics a run has are the ones it used (cmd_vel's type is
                # the one the node was started with).
                connection = self._writer.add_connection(topic, msgtype, typestore=self._types)
                self._connections[topic] = connection
            self._writer.write(connection, log_ns, serialize_message(message))
        except OSError as exc:
            self.failed = f"--bag {self.path}: recording stopped: {exc.strerror or exc}"
            self.close()
            return self.failed
        self.messages += 1
        return None

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.close()
        except OSError:
            with contextlib.suppress(Exception):
                self._writer.abort()


def _msgtype(message: Any) -> str:
    """``geometry_msgs/msg/Twist`` from an rclpy message's class (its module path)."""
    cls = type(message)
    package = cls.__module__.split(".")[0]
    return f"{package}/msg/{cls.__name__}"
