"""``ros2 launch fpgalink fpgalink.launch.py``: the node ``fpgalink`` and, where the system
ROS has it, robot_state_publisher with the same URDF (which then publishes /tf_static and
the wheels' transforms from joint_states; the node's own /tf_static is turned off).

Arguments (``name:=value``):

- ``ports``: ``L=/dev/… R=/dev/…`` (space-separated ``NAME=URL``); empty: ``fpgalink.toml``
  or the environment, else the emulated robot in the node's process (as ``fpgalink-ros2``)
- ``robot``: a robot description (TOML); empty: the config file's or the seed's robot
- ``namespace``: the node's namespace (and frame prefix, as diff_drive_controller's)
- ``use_sim_time``: ``true`` to run on /clock (the emulated robot publishes it)
- ``robot_state_publisher``: ``auto`` (when installed), ``true`` or ``false``
"""

from __future__ import annotations

from typing import Any

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

ARGUMENTS = {
    "ports": ("", "the boards' ports, NAME=URL separated by spaces (empty: as "
                  "fpgalink-ros2 finds them)"),
    "robot": ("", "robot description (TOML); empty: the config file's or the seed's"),
    "namespace": ("", "the node's namespace"),
    "use_sim_time": ("false", "run on /clock"),
    "robot_state_publisher": ("auto", "start robot_state_publisher: auto, true or false"),
}


def _have_robot_state_publisher() -> bool:
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        get_package_prefix("robot_state_publisher")
    except PackageNotFoundError:
        return False
    return True


def _urdf(robot: str) -> str:
    """The URDF the node publishes by default: generated from the same description."""
    from fpgalink.protocol.robot import load_robot, seed_robot
    from fpgalink.protocol.urdf import robot_urdf

    return robot_urdf(load_robot(robot) if robot else seed_robot())


def _frame_prefix(namespace: str) -> str:
    """The node's tf_frame_prefix rule for its namespace (``bot`` → ``bot/``)."""
    prefix = namespace.strip("/")
    return f"{prefix}/" if prefix else ""


def _nodes(context: Any) -> list[Any]:
    def value(name: str) -> str:
        return str(LaunchConfiguration(name).perform(context)).strip()

    ports, robot, namespace = value("ports"), value("robot"), value("namespace")
    sim_time = value("use_sim_time").lower() in ("true", "1", "yes")
    wanted = value("robot_state_publisher").lower()
    with_rsp = _have_robot_state_publisher() if wanted == "auto" else wanted in (
        "true", "1", "yes")
    arguments = [f"--port={port}" for port in ports.split()]
    if robot:
        arguments.append(f"--robot={robot}")
    nodes = [Node(package="fpgalink", executable="fpgalink-ros2", name="fpgalink",
                  namespace=namespace, output="screen", arguments=arguments,
                  parameters=[{"use_sim_time": sim_time,
                               "publish_static_tf": not with_rsp}])]
    if with_rsp:
        nodes.append(Node(package="robot_state_publisher", executable="robot_state_publisher",
                          namespace=namespace, output="screen",
                          parameters=[{"robot_description": _urdf(robot),
                                       "frame_prefix": _frame_prefix(namespace),
                                       "use_sim_time": sim_time}]))
    return nodes


def generate_launch_description() -> Any:
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, (default, text) in ARGUMENTS.items()]
        + [OpaqueFunction(function=_nodes)])
