"""The robot on ROS 2 (``fpgalink-ros2``): joint states, odometry, diagnostics, cmd_vel,
wheel references, goals, the deadman, and the boards' parameters as ROS parameters.

Needs ROS 2 Jazzy's Python packages: ``pip install 'fpgalink[ros2]'`` (the community wheels
from PyPI, pinned), or a sourced system ROS 2 Jazzy. Nothing else in fpgalink imports this
package. See docs/ros2.md.
"""

from __future__ import annotations

__all__ = ["ROS2_INSTALL_HINT", "available"]

ROS2_INSTALL_HINT = (
    "needs ROS 2 Jazzy's Python packages: pip install 'fpgalink[ros2]' (PyPI wheels, "
    "x86-64 Linux), or source a ROS 2 Jazzy installation (. /opt/ros/jazzy/setup.bash)"
)


def available() -> bool:
    """rclpy and the message packages import here."""
    try:
        import diagnostic_msgs.msg  # noqa: F401
        import geometry_msgs.msg  # noqa: F401
        import nav_msgs.msg  # noqa: F401
        import rclpy  # noqa: F401
        import sensor_msgs.msg  # noqa: F401
    except ImportError:
        return False
    return True
