"""The robot into a rosbag2 (``--rosbag2 DIR``): MCAP storage, CDR messages with ``ros2msg``
schemas, written with the ``rosbags`` library (no ROS installation needed), so
``ros2 bag play``, Foxglove and PlotJuggler open it.

Topics, as the ROS 2 node publishes them (docs/ros2.md): ``/joint_states``
(``sensor_msgs/JointState``, each set of the boards' samples), ``/odom``
(``nav_msgs/Odometry``), ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``, 1 Hz) and,
for an emulated robot, ``/truth`` (``nav_msgs/Odometry``, the body's true motion, 100 Hz at
most). A message's bag timestamp is when the host received it (as ``ros2 bag record``
does); header stamps are the boards' sample times on the host clock.

The bag goes the way every recording goes (:class:`fpgalink.recording.BagRecording`): made
as ``DIR.partial/DIR`` and renamed into place when closed, an existing ``DIR`` refused unless
``--force``; its MCAP file has CRCs, and room kept for its summary and ``metadata.yaml``, so
a full disk stops the recording with the bag complete up to there.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from fpgalink.cli.output import CliError, ExitCode
from fpgalink.protocol.robot import RobotDescription
from fpgalink.recording import BagRecording, BagStorage, RecordingError
from fpgalink.robot.health import Status
from fpgalink.robot.joints import JointStates
from fpgalink.robot.odometry import OdometryState

__all__ = ["ROSBAGS_HINT", "RosbagWriter"]

ROSBAGS_HINT = "--rosbag2 needs the rosbags library: pip install 'fpgalink[ros2]'"


class RosbagWriter:
    """One bag. ``truth``: whether to carry the emulated robot's ``/truth`` topic. A write
    that fails raises :class:`~fpgalink.recording.RecordingError` (the recording stops);
    :meth:`close` says, by raising it, what is on disk."""

    def __init__(self, path: Path, description: RobotDescription, *, truth: bool,
                 metadata: dict[str, str], force: bool) -> None:
        try:
            from rosbags.interfaces import (
                Qos,
                QosDurability,
                QosHistory,
                QosLiveliness,
                QosReliability,
                QosTime,
            )
            from rosbags.rosbag2 import StoragePlugin, Writer
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise CliError(ROSBAGS_HINT, ExitCode.NOT_INSTALLED) from None

        class McapWriter(Writer):
            """rosbags' writer, its MCAP storage the recording's own."""

            STORAGE_PLUGINS = {StoragePlugin.MCAP: BagStorage}  # noqa: RUF012

        self.path = path
        self.description = description
        self.types = get_typestore(Stores.ROS2_JAZZY)
        self._bag = BagRecording(
            path, force=force,
            writer=lambda where: McapWriter(where, version=9,
                                            storage_plugin=StoragePlugin.MCAP),
            custom_data={f"fpgalink.{key}": value for key, value in metadata.items()})
        never = QosTime(sec=0x7FFFFFFF, nsec=0xFFFFFFFF)

        def qos(reliability: Any, depth: int) -> list[Any]:
            return [Qos(history=QosHistory.KEEP_LAST, depth=depth, reliability=reliability,
                        durability=QosDurability.VOLATILE, deadline=never, lifespan=never,
                        liveliness=QosLiveliness.AUTOMATIC,
                        liveliness_lease_duration=never,
                        avoid_ros_namespace_conventions=False)]

        sensor = qos(QosReliability.BEST_EFFORT, 5)  # joint_states: the node's sensor QoS
        reliable = qos(QosReliability.RELIABLE, 10)
        topics = [("/joint_states", "sensor_msgs/msg/JointState", sensor),
                  ("/odom", "nav_msgs/msg/Odometry", reliable),
                  ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", reliable)]
        if truth:
            topics.append(("/truth", "nav_msgs/msg/Odometry", reliable))
        try:
            self._connections = {
                topic: self._bag.add_connection(topic, msgtype, typestore=self.types,
                                                offered_qos_profiles=profiles)
                for topic, msgtype, profiles in topics}
        except BaseException:
            with contextlib.suppress(RecordingError):
                self._bag.close()
            raise

    @property
    def messages(self) -> int:
        return self._bag.messages

    # --- messages -------------------------------------------------------------------------

    def _header(self, stamp_ns: int, frame_id: str) -> Any:
        t = self.types.types
        stamp = t["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000,
                                                 nanosec=stamp_ns % 1_000_000_000)
        return t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def _write(self, topic: str, message: Any, log_ns: int) -> None:
        data = self.types.serialize_cdr(message, message.__msgtype__)
        self._bag.write(self._connections[topic], log_ns, data)

    def joint_states(self, states: JointStates, stamp_ns: int, log_ns: int) -> None:
        import numpy as np

        message = self.types.types["sensor_msgs/msg/JointState"](
            header=self._header(stamp_ns, ""), name=list(states.names),
            position=np.array(states.position, dtype=np.float64),
            velocity=np.array(states.velocity, dtype=np.float64),
            effort=np.array(states.effort, dtype=np.float64))
        self._write("/joint_states", message, log_ns)

    def _odometry(self, stamp_ns: int, x: float, y: float, theta: float, v: float,
                  omega: float, covariance: Sequence[float]) -> Any:
        import numpy as np

        t = self.types.types
        point = t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0)
        turn = t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(theta / 2),
                                                 w=math.cos(theta / 2))
        vector = t["geometry_msgs/msg/Vector3"]
        twist = t["geometry_msgs/msg/Twist"](linear=vector(x=float(v), y=0.0, z=0.0),
                                             angular=vector(x=0.0, y=0.0, z=float(omega)))
        return t["nav_msgs/msg/Odometry"](
            header=self._header(stamp_ns, "odom"), child_frame_id="base_link",
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=t["geometry_msgs/msg/Pose"](position=point, orientation=turn),
                covariance=np.array(covariance, dtype=np.float64)),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=twist, covariance=np.zeros(36, dtype=np.float64)))

    def odometry(self, state: OdometryState, stamp_ns: int, log_ns: int) -> None:
        pose = state.pose
        self._write("/odom", self._odometry(stamp_ns, pose.x, pose.y, pose.theta, state.v,
                                            state.omega, state.covariance_6x6()), log_ns)

    def truth(self, record: dict[str, Any], stamp_ns: int, log_ns: int) -> None:
        self._write("/truth", self._odometry(stamp_ns, record["x"], record["y"],
                                             record["theta"], record["v"], record["omega"],
                                             [0.0] * 36), log_ns)

    def diagnostics(self, statuses: Sequence[Status], stamp_ns: int, log_ns: int) -> None:
        t = self.types.types
        status = t["diagnostic_msgs/msg/DiagnosticStatus"]
        pair = t["diagnostic_msgs/msg/KeyValue"]
        message = t["diagnostic_msgs/msg/DiagnosticArray"](
            header=self._header(stamp_ns, ""),
            status=[status(level=int(s.level), name=f"fpgalink: {s.name}", message=s.message,
                           hardware_id=s.hardware_id,
                           values=[pair(key=k, value=v) for k, v in s.values])
                    for s in statuses])
        self._write("/diagnostics", message, log_ns)

    # --- the end --------------------------------------------------------------------------

    def close(self) -> None:
        """Close the bag (its index, ``metadata.yaml``) and put it in place;
        :class:`~fpgalink.recording.RecordingError` when it stopped early or cannot be."""
        self._bag.close()
