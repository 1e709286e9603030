"""Without ROS 2 installed: the rest of fpgalink imports and works, and ``fpgalink-ros2``
says how to install it (exit 8), while ``--help`` still answers. rclpy is hidden from a
child interpreter (``sys.modules['rclpy'] = None`` makes every import of it fail)."""

from __future__ import annotations

import subprocess
import sys

HIDE_ROS = ("import sys\n"
            "for name in ('rclpy', 'sensor_msgs', 'geometry_msgs', 'nav_msgs',"
            " 'diagnostic_msgs', 'std_msgs'):\n"
            "    sys.modules[name] = None\n")


def run(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", HIDE_ROS + code], capture_output=True,
                          text=True, timeout=60, check=False)


def test_the_command_says_how_to_install_ros2() -> None:
    result = run("from fpgalink.ros2.__main__ import main\nmain(['fpgalink-ros2'])")
    assert result.returncode == 8  # not installed (the one exit-code table)
    assert "pip install 'fpgalink[ros2]'" in result.stderr
    assert "/opt/ros/jazzy/setup.bash" in result.stderr
    assert "Traceback" not in result.stderr


def test_help_answers_without_ros2() -> None:
    result = run("from fpgalink.ros2.__main__ import main\nmain(['fpgalink-ros2', '--help'])")
    assert result.returncode == 0
    assert "--port NAME=URL" in result.stdout and "--ros-args" in result.stdout


def test_the_library_and_the_cli_do_not_need_ros2() -> None:
    result = run("import fpgalink, fpgalink.robot, fpgalink.cli, fpgalink.ros2\n"
                 "from fpgalink.ros2 import available\n"
                 "assert not available()\n"
                 "assert 'rclpy' not in [m for m, v in sys.modules.items() if v is not None]\n"
                 "print('ok')")
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "ok"


def test_version_and_the_exit_code_table_without_ros2() -> None:
    # issue 26: --version as the CLI has it, and the exit codes in --help.
    result = run("from fpgalink.ros2.__main__ import main\nmain(['fpgalink-ros2', '--version'])")
    assert result.returncode == 0, result.stderr
    from fpgalink import __version__

    assert result.stdout.strip() == f"fpgalink-ros2 {__version__}"
    result = run("from fpgalink.ros2.__main__ import main\nmain(['fpgalink-ros2', '--help'])")
    assert result.returncode == 0
    table = " ".join(result.stdout[result.stdout.index("Exit codes"):].split())
    for code in ("0 ok", "2 bad input", "4 board not answering", "5 port missing",
                 "8 an optional part not installed"):
        assert code in table
