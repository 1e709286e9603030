"""The node's messages, built from the robot's state: pure functions of what they carry
(``joint_states``, ``odom`` and its ``/tf``, ``truth``, ``imu/data``, ``/tf_static``,
``/diagnostics``, ``cmd_vel_out``, ``/clock``), so the node is left with when to publish."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import TransformStamped, TwistStamped
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState

from fpgalink.protocol.urdf import FixedJoint
from fpgalink.robot.drive import WheelCommand
from fpgalink.robot.health import Status
from fpgalink.robot.joints import JointStates
from fpgalink.robot.odometry import OdometryState

__all__ = ["clock_message", "diagnostic_status", "imu_message", "joint_state_message",
           "limited_velocity_message", "odometry_message", "static_transforms", "time_msg",
           "transform_of", "truth_message"]


def time_msg(ns: int) -> TimeMsg:
    return TimeMsg(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def joint_state_message(states: JointStates, names: Mapping[str, str], stamp_ns: int
                        ) -> JointState:
    """The wheels as joints, named as ``names`` has them (the robot's name → the node's)."""
    message = JointState()
    message.header.stamp = time_msg(stamp_ns)
    message.name = [names.get(name, name) for name in states.names]
    message.position = list(states.position)
    message.velocity = list(states.velocity)
    message.effort = list(states.effort)
    return message


def odometry_message(state: OdometryState, stamp_ns: int, frame: str, child: str,
                     pose_diagonal: Sequence[float] | None,
                     twist_diagonal: Sequence[float]) -> Odometry:
    """``odom``: the pose (its covariance the odometry's own, or ``pose_diagonal``), body
    speed and yaw rate."""
    message = Odometry()
    message.header.stamp = time_msg(stamp_ns)
    message.header.frame_id = frame
    message.child_frame_id = child
    _pose_into(message, state.pose.x, state.pose.y, state.pose.theta)
    message.twist.twist.linear.x = state.v
    message.twist.twist.angular.z = state.omega
    message.pose.covariance = state.covariance_6x6() if pose_diagonal is None \
        else _diagonal(pose_diagonal)
    message.twist.covariance = _diagonal(twist_diagonal)
    return message


def transform_of(message: Odometry) -> TransformStamped:
    """``odom``'s pose as ``/tf`` carries it: the same at the same stamp."""
    transform = TransformStamped()
    transform.header = message.header
    transform.child_frame_id = message.child_frame_id
    transform.transform.translation.x = message.pose.pose.position.x
    transform.transform.translation.y = message.pose.pose.position.y
    transform.transform.rotation = message.pose.pose.orientation
    return transform


def truth_message(truth: Mapping[str, Any], like: Odometry) -> Odometry:
    """The emulated body's true motion, in ``like``'s frames at its stamp."""
    true = Odometry()
    true.header = like.header
    true.child_frame_id = like.child_frame_id
    _pose_into(true, truth["x"], truth["y"], truth["theta"])
    true.twist.twist.linear.x = float(truth["v"])
    true.twist.twist.angular.z = float(truth["omega"])
    return true


def imu_message(reading: Mapping[str, Any], frame: str, stamp: TimeMsg) -> Imu:
    """An emulated IMU's reading: angular velocity and linear acceleration (each the mean
    since the previous reading, with the emulated noise and bias, their variances on the
    diagonals); no orientation (covariance[0] = −1), as a 6-axis IMU gives none."""
    message = Imu()
    message.header.stamp = stamp
    message.header.frame_id = frame
    gyro, accel = reading["angular_velocity"], reading["linear_acceleration"]
    (message.angular_velocity.x, message.angular_velocity.y,
     message.angular_velocity.z) = (float(v) for v in gyro)
    (message.linear_acceleration.x, message.linear_acceleration.y,
     message.linear_acceleration.z) = (float(v) for v in accel)
    gyro_var = float(reading.get("angular_velocity_variance", 0.0))
    accel_var = float(reading.get("linear_acceleration_variance", 0.0))
    message.angular_velocity_covariance = [gyro_var, 0.0, 0.0, 0.0, gyro_var, 0.0,
                                           0.0, 0.0, gyro_var]
    message.linear_acceleration_covariance = [accel_var, 0.0, 0.0, 0.0, accel_var,
                                              0.0, 0.0, 0.0, accel_var]
    message.orientation_covariance = [-1.0] + [0.0] * 8
    return message


def static_transforms(joints: Sequence[FixedJoint], prefix: str, stamp: TimeMsg
                      ) -> list[TransformStamped]:
    """The URDF's fixed joints, as robot_state_publisher puts them on /tf_static."""
    transforms = []
    for joint in joints:
        transform = TransformStamped()
        transform.header.stamp = stamp
        transform.header.frame_id = prefix + joint.parent
        transform.child_frame_id = prefix + joint.child
        (transform.transform.translation.x, transform.transform.translation.y,
         transform.transform.translation.z) = joint.xyz
        q = transform.transform.rotation
        q.x, q.y, q.z, q.w = _quaternion(*joint.rpy)
        transforms.append(transform)
    return transforms


def limited_velocity_message(command: WheelCommand, stamp: TimeMsg, frame: str
                             ) -> TwistStamped:
    """``cmd_vel_out``: what the wheels were asked, after the limits."""
    out = TwistStamped()
    out.header.stamp = stamp
    out.header.frame_id = frame
    out.twist.linear.x, out.twist.angular.z = command.v, command.omega
    return out


def clock_message(seconds: float) -> Clock:
    return Clock(clock=time_msg(round(seconds * 1e9)))


def diagnostic_status(status: Status, node_name: str) -> DiagnosticStatus:
    return DiagnosticStatus(level=bytes([status.level]), name=f"{node_name}: {status.name}",
                            message=status.message, hardware_id=status.hardware_id,
                            values=[KeyValue(key=k, value=v) for k, v in status.values])


def _pose_into(message: Odometry, x: float, y: float, theta: float) -> None:
    message.pose.pose.position.x = float(x)
    message.pose.pose.position.y = float(y)
    message.pose.pose.orientation.z = math.sin(theta / 2.0)
    message.pose.pose.orientation.w = math.cos(theta / 2.0)


def _diagonal(values: Sequence[float]) -> list[float]:
    matrix = [0.0] * 36
    for index, value in enumerate(values):
        matrix[index * 7] = float(value)
    return matrix


def _quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of URDF's fixed-axis roll, pitch, yaw."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)
