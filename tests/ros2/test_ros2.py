"""The ROS 2 node against a real rclpy peer (tests/ros2/peer.py, a separate process using
plain rclpy), with ``fpgaemu serve`` boards over ptys. Every process that creates a DDS
participant runs inside tests/ros2/netns.sh: a private network namespace with loopback only.

Both scenarios start at once (each in its own namespace) and each test waits for its
scenario's verdicts. Without the ``ros2`` extra, or where network namespaces cannot be made,
the tests skip, unless ``FPGALINK_REQUIRE_ROS2=1`` (set by ``make test``): a failure then."""

from __future__ import annotations

import contextlib
import importlib.util
import json
import math
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]
NETNS = ROOT / "tests" / "ros2" / "netns.sh"
SCENARIO_TIMEOUT_S = 300


def _why_unavailable() -> str | None:
    if importlib.util.find_spec("rclpy") is None:
        return "rclpy is not installed (pip install -e '.[ros2]' -c ros2-constraints.txt)"
    probe = subprocess.run([str(NETNS), "true"], capture_output=True, text=True, check=False)
    if probe.returncode != 0:
        return f"no private network namespace here: {probe.stderr.strip()}"
    return None


_missing = _why_unavailable()
if _missing is not None and os.environ.get("FPGALINK_REQUIRE_ROS2") == "1":
    raise RuntimeError(f"the ROS 2 tests must run here: {_missing}")
pytestmark = [pytest.mark.skipif(_missing is not None, reason=_missing or ""),
              pytest.mark.timeout(SCENARIO_TIMEOUT_S + 60)]


def docs_example() -> str:
    """The rclpy example of docs/ros2.md, as written there."""
    text = (ROOT / "docs" / "ros2.md").read_text(encoding="utf-8")
    section = text[text.index("## An example session"):]
    return section.split("```python\n", 1)[1].split("```", 1)[0]


class Scenario:
    def __init__(self, name: str, log_dir: Path) -> None:
        env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                   ROS_LOG_DIR=str(log_dir), PYTHONPATH=str(ROOT),
                   PYTHONUNBUFFERED="1", RCUTILS_COLORIZED_OUTPUT="0")
        self.name = name
        command = [sys.executable, "-m", "tests.ros2.peer", name]
        if name == "docs":  # the node on the emulated robot, then the docs' example
            example = log_dir / "docs_example.py"
            example.write_text(docs_example(), encoding="utf-8")
            command = ["sh", "-c", f"{sys.executable} -m fpgalink.ros2 & node=$!; "
                       f"{sys.executable} {example}; rc=$?; kill -INT $node; wait $node; "
                       "echo node exit $?; exit $rc"]
        # A session of its own: a timeout kills the peer with everything it started.
        self.proc = subprocess.Popen(
            [str(NETNS), *command], cwd=ROOT, env=env, start_new_session=True,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self._checks: dict[str, dict[str, Any]] | None = None
        self.output = ""

    def checks(self) -> dict[str, dict[str, Any]]:
        if self._checks is None:
            try:
                self.output, _ = self.proc.communicate(timeout=SCENARIO_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.kill()
                self.output, _ = self.proc.communicate()
                pytest.fail(f"peer {self.name} ran over {SCENARIO_TIMEOUT_S} s:\n{self.output}")
            self._checks = {}
            if self.proc.returncode != 0:
                pytest.fail(f"peer {self.name} exited {self.proc.returncode}:\n{self.output}")
            for line in self.output.splitlines():
                if line.startswith('{"check"'):
                    facts = json.loads(line)
                    self._checks[facts.pop("check")] = facts
        return self._checks

    def kill(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGKILL)

    def check(self, name: str) -> dict[str, Any]:
        checks = self.checks()
        assert name in checks, f"peer {self.name} did not get to {name!r}:\n{self.output}"
        return checks[name]


@pytest.fixture(scope="module")
def scenarios(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Scenario]]:
    log_dir = tmp_path_factory.mktemp("roslog")
    running = {name: Scenario(name, log_dir) for name in ("main", "kill", "docs", "imu")}
    yield running
    for scenario in running.values():
        scenario.kill()  # whatever it started too, finished or not
        scenario.proc.wait()


def test_joint_states_carry_each_boards_telemetry_in_rad_s_on_its_clock(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["main"].check("joint_states")
    assert facts["names"] == ["FL", "BL", "FR", "BR"]
    # Each truth line is a tick the boards sampled (50 a second while driving 2 s). With the
    # one offset that maps board time onto ROS time, the message stamped at that tick holds
    # that tick's speeds, float32 then rad/s, exactly.
    assert facts["moving_lines"] >= 20
    assert facts["at_stamp"] >= 10, facts
    assert facts["equal_left"] == facts["at_stamp"], facts
    # The right board's sample is its latest at publishing: at most a tick from the left's.
    assert facts["equal_right"] >= 1, facts
    # 1 kHz configured: never two messages for one sample, never faster than the ticks.
    assert facts["distinct_stamps"] == facts["messages"]
    assert facts["increasing"]
    assert facts["min_gap_ms"] >= 1.0 - 1e-6


def test_cmd_vel_moves_the_body_and_odom_follows_it(scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["main"].check("cmd_vel")
    assert facts["distance"] > 0.2  # 2 s at 0.2 m/s asked: it moved
    error = math.dist((facts["truth_x"], facts["truth_y"]), (facts["odom_x"], facts["odom_y"]))
    assert error <= 0.02 * facts["distance"]
    assert abs(facts["truth_theta"] - facts["odom_theta"]) <= math.radians(3)
    assert facts["truth_theta"] > math.radians(5)  # it turned left, as asked


def test_goal_pose_brings_the_robot_to_the_goal(scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["main"].check("goal_pose")
    miss = math.dist((facts["goal_x"], facts["goal_y"]), (facts["truth_x"], facts["truth_y"]))
    assert miss <= 0.06  # the goal tolerance (0.05 m in odometry) plus odometry's drift


def test_set_parameters_is_confirmed_by_the_board_or_refused_with_the_reason(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["main"].check("parameters")
    assert facts["ok"] is True and facts["reason"] == ""
    assert facts["on_board"] == 400.0
    assert facts["bad_ok"] is False
    assert "Kp_Wheel_Pid" in facts["bad_reason"] and "-1" in facts["bad_reason"]
    assert facts["after"] == 400.0 and facts["board_after"] == 400.0
    # Telemetry is what the node runs on: turning it off is refused, and it stays on.
    assert facts["silence_ok"] is False and "telemetry" in facts["silence_reason"]
    assert facts["streaming"] == 1


def test_enable_silence_stops_the_wheels(scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["main"].check("enable_silence")
    for name, driven in facts["driven"].items():
        assert driven["enabled"] and any(driven["pwm"]), f"board {name} was not driven"
        stopped = facts["stopped"][name]
        assert not stopped["enabled"] and stopped["pwm_a"] == stopped["pwm_b"] == 0
        # global_enable gates the PWM in logic: 0 from the cycle enable fell, which is
        # within the board's 300 ms of its last RE whichever side stopped it.
        assert stopped["disabled_s"] > driven["now_s"]
        assert 0 <= stopped["disabled_s"] - stopped["last_re_s"] <= 0.3
    # The node's deadman is 0.5 s: never sooner than that after the last `true`.
    assert "deadman" in facts["reason"]
    assert facts["host_wait_s"] >= 0.45


def test_nodes_and_servers_exit_cleanly(scenarios: dict[str, Scenario]) -> None:
    assert scenarios["main"].check("node_exit")["code"] == 0
    assert scenarios["main"].check("serve_exit")["code"] == 0
    assert scenarios["kill"].check("node_exit")["code"] == 0
    assert "Traceback" not in scenarios["main"].output + scenarios["kill"].output


def test_ros_arguments_are_honoured(scenarios: dict[str, Scenario]) -> None:
    # The kill scenario's node runs with `-r __ns:=/bot -p L.Kp_Wheel_Pid.B:=350.0`: its
    # topics and services are found in /bot, and the -p value was set on board L (its
    # echo confirmed it) while channel A kept the board's own value.
    facts = scenarios["kill"].check("ros_args")
    assert facts["namespace"] == "/bot"
    assert facts["kp_b"] == 350.0
    assert facts["kp_a"] != 350.0 and facts["kp_a"] > 0


def test_a_killed_board_server_turns_its_status_to_error_and_disables_the_robot(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["kill"].check("kill")
    assert facts["board_l"] == [2, "not answering"]
    assert facts["board_r"][0] == 0
    level, message = facts["supervision"]
    assert level == 2 and "board L" in message


def test_the_example_session_in_the_docs_runs_as_shown(scenarios: dict[str, Scenario]
                                                       ) -> None:
    scenarios["docs"].checks()  # it ran to the end, exit 0
    lines = scenarios["docs"].output.splitlines()
    printed = [line for line in lines if not line.startswith("[")]  # the node's log: [INFO]
    joints = next(line for line in printed if line.startswith("joint_states:"))
    assert "['FL', 'BL', 'FR', 'BR']" in joints
    speeds = [float(v) for v in joints.split("] [")[1].split("]")[0].replace("'", "").split(",")]
    assert speeds[2] > speeds[0] > 0  # forward, turning left
    assert next(line for line in printed if line.startswith("odom:"))
    assert [line for line in printed if line.startswith("diagnostics:")] == [
        "diagnostics: fpgalink: board L: level 0 alive",
        "diagnostics: fpgalink: board R: level 0 alive",
        "diagnostics: fpgalink: supervision: level 0 enabled"]
    assert "set L.Kp_Wheel_Pid.A = 400.0: successful=True " in printed
    assert ("set L.Kp_Wheel_Pid.A = -1.0: successful=False board L: Kp_Wheel_Pid must be a "
            "float ≥ 0 (and fit a float32); got -1.0") in printed
    assert "node exit 0" in printed


def test_the_emulated_bodys_imu_is_published_on_imu_data(
        scenarios: dict[str, Scenario]) -> None:
    rest = scenarios["imu"].check("imu_rest")
    assert rest["frame_id"] == "ImuALink"
    assert rest["rate_hz"] > 25  # 50 Hz nominal, on a loaded machine fewer
    assert rest["orientation_covariance"] == -1.0  # a 6-axis IMU gives no orientation
    assert rest["gyro_variance"] > 0 and rest["accel_variance"] > 0
    assert math.isclose(rest["az"], 9.81, abs_tol=0.3) and abs(rest["ax"]) < 0.3
    assert abs(rest["gz"]) < math.radians(2)
    turning = scenarios["imu"].check("imu_turning")
    assert turning["samples"] > 20
    assert turning["truth_omega"] > 0.1
    assert math.isclose(turning["gz"], turning["truth_omega"], rel_tol=0.2, abs_tol=0.03)
    assert scenarios["imu"].check("imu_node_exit")["code"] == 0
