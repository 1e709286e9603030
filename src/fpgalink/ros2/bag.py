"""``fpgalink-ros2 --bag DIR``: the node's own inputs (as received) and outputs (as
published) into a rosbag2 — version 9, MCAP storage, CDR — written with ``rosbags`` (no
``ros2 bag`` needed), so a run can be replayed with ``ros2 bag play`` or read with
Foxglove, PlotJuggler or ``rosbags``.

Each message is serialised by rclpy exactly as it went over DDS and written under its
resolved topic name (``/bot/odom`` in a namespace); its bag time is the node's clock when
it was published or handed to the node (the ROS clock: /clock time under
``use_sim_time``), as ``ros2 bag record`` stamps what it receives. Every write happens on
the asyncio thread (subscriptions hand their messages there first), so the writer needs no
lock.

The bag goes the way every recording goes (:class:`fpgalink.recording.BagRecording`): made
as ``DIR.partial/DIR`` and renamed into place when the node ends, an existing ``DIR``
refused unless ``--force``, its MCAP file with CRCs and room kept for its summary. A write
that fails (a full disk) ends the recording with one error line, the node goes on; when the
node ends the bag is closed complete up to there and :meth:`NodeBag.close` says so (the
node then exits 1).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fpgalink.recording import (
    BagRecording,
    BagStorage,
    OutputBusy,
    OutputRefused,
    RecordingError,
)

__all__ = ["BagError", "NodeBag"]


class BagError(Exception):
    """The bag cannot be made, or was not written whole: one line saying why, and the
    node's exit code for it (2: the DIR given cannot be taken; 1: a disk that failed)."""

    def __init__(self, message: str, code: int = 1) -> None:
        super().__init__(message)
        self.code = code


class NodeBag:
    """One bag for one run of the node."""

    def __init__(self, path: Path, metadata: dict[str, str], *, force: bool = False) -> None:
        try:
            from rosbags.rosbag2 import StoragePlugin, Writer
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise BagError("--bag needs the rosbags library: pip install 'fpgalink[ros2]'"
                           ) from None

        class McapWriter(Writer):
            """rosbags' writer, its MCAP storage the recording's own."""

            STORAGE_PLUGINS = {StoragePlugin.MCAP: BagStorage}  # noqa: RUF012

        self.path = path
        #: why the recording stopped early (one line), once it has
        self.failed: str | None = None
        self._types = get_typestore(Stores.ROS2_JAZZY)
        try:
            self._bag = BagRecording(
                path, force=force,
                writer=lambda where: McapWriter(where, version=9,
                                                storage_plugin=StoragePlugin.MCAP),
                custom_data={f"fpgalink.{key}": value for key, value in metadata.items()})
        except OutputRefused as exc:
            raise BagError(f"--bag {exc}" + ("; --force replaces it" if exc.exists else ""),
                           2) from None
        except OutputBusy as exc:
            raise BagError(f"--bag {exc}", 2) from None
        except RecordingError as exc:
            raise BagError(f"--bag {exc}") from None
        self._connections: dict[str, Any] = {}
        self._closed = False

    @property
    def messages(self) -> int:
        return self._bag.messages

    def set_metadata(self, metadata: dict[str, str]) -> None:
        """More of the bag's ``metadata.yaml`` custom data (``fpgalink.KEY``), known once the
        robot started: who its boards are."""
        self._bag.set_custom_data({f"fpgalink.{key}": value for key, value in metadata.items()})

    def write(self, topic: str, message: Any, log_ns: int) -> str | None:
        """``message`` (an rclpy message) on ``topic``; returns why the recording just
        stopped, once, or ``None``."""
        if self._closed or self.failed is not None:
            return None
        from rclpy.serialization import serialize_message

        try:
            connection = self._connections.get(topic)
            if connection is None:
                # On first use: the topics a run has are the ones it used (cmd_vel's type is
                # the one the node was started with).
                connection = self._bag.add_connection(topic, _msgtype(message),
                                                      typestore=self._types)
                self._connections[topic] = connection
            self._bag.write(connection, log_ns, serialize_message(message))
        except RecordingError:
            # Closed at once, complete up to here; the line says what is on disk.
            self._closed = True
            try:
                self._bag.close()
            except RecordingError as exc:
                self.failed = f"--bag {exc}"
            return self.failed
        return None

    def close(self) -> None:
        """Close the bag and put it in place; :class:`BagError` (one line) when the recording
        stopped early or the bag cannot be finished."""
        if not self._closed:
            self._closed = True
            try:
                self._bag.close()
            except RecordingError as exc:
                self.failed = f"--bag {exc}"
        if self.failed is not None:
            raise BagError(self.failed)


def _msgtype(message: Any) -> str:
    """``geometry_msgs/msg/Twist`` from an rclpy message's class (its module path)."""
    cls = type(message)
    package = cls.__module__.split(".")[0]
    return f"{package}/msg/{cls.__name__}"
