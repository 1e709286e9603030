"""The ROS 2 node against a real rclpy peer (tests/ros2/peer.py, a separate process using
plain rclpy), with ``fpgaemu serve`` boards over ptys. Every process that creates a DDS
participant runs inside tests/ros2/netns.sh: a private network namespace with loopback only.

The scenarios run each in its own namespace (``main``, ``kill`` and ``docs`` at once,
``fault``, ``ddc`` and ``imu`` after them, ``describe`` last) and each test waits for its
scenario's verdicts. Without the ``ros2`` extra, or where network namespaces cannot be made,
the tests skip, unless ``FPGALINK_REQUIRE_ROS2=1`` (set by ``make test``): a failure then."""

from __future__ import annotations

import contextlib
import importlib.util
import itertools
import json
import math
import os
import signal
import statistics
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from fpgalink.boardclock import MAX_SLEW

ROOT = Path(__file__).resolve().parents[2]
NETNS = ROOT / "tests" / "ros2" / "netns.sh"
SCENARIO_TIMEOUT_S = 300


def _why_unavailable() -> str | None:
    if importlib.util.find_spec("rclpy") is None:
        return "rclpy is not installed (pip install -e '.[ros2]' -c ros2-constraints.txt)"
    if importlib.util.find_spec("tf2_msgs") is None:
        return "tf2_msgs is not generated (fpgalink-ros2 --install-tf2, or make tf2-msgs)"
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
                   ROS_LOG_DIR=str(log_dir),
                   # This checkout's code, whichever fpgalink the interpreter has installed.
                   PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)]),
                   PYTHONUNBUFFERED="1", RCUTILS_COLORIZED_OUTPUT="0")
        self.name = name
        #: the peer's checks, one JSON line each: a file of their own, never the output it
        #: shares with the node's and serve's logs (where a line could be glued to another)
        self.report = log_dir / f"{name}.checks.jsonl"
        command = [sys.executable, "-m", "tests.ros2.peer", name, str(self.report)]
        if name == "docs":  # the node on the emulated robot, then the docs' example
            example = log_dir / "docs_example.py"
            example.write_text(docs_example(), encoding="utf-8")
            # The node's log to a file of its own: the example's printed lines are checked
            # as printed, never glued to one of the node's.
            node_log = log_dir / "docs_node.log"
            command = ["sh", "-c", f"{sys.executable} -m fpgalink.ros2 > {node_log} 2>&1 & "
                       "node=$!; "
                       f"{sys.executable} {example}; rc=$?; kill -INT $node; wait $node; "
                       "echo node exit $?; exit $rc"]
        # A session of its own: a timeout kills the peer with everything it started.
        self.proc = subprocess.Popen(
            [str(NETNS), *command], cwd=ROOT, env=env, start_new_session=True,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self._checks: dict[str, dict[str, Any]] | None = None
        self._ran_over = False
        self.output = ""
        #: the peer's whole output, kept for a failure's diagnosis (pytest keeps the last
        #: three runs' temporary directories; the nodes' own logs are beside it)
        self.saved = log_dir / f"{name}.out"

    def finish(self) -> bool:
        """Wait for the peer to end (killed after the time limit); False if it ran over."""
        if self.proc.returncode is None:
            try:
                self.output, _ = self.proc.communicate(timeout=SCENARIO_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.kill()
                self.output, _ = self.proc.communicate()
                self._ran_over = True
            self.saved.write_text(self.output, encoding="utf-8")
        return not self._ran_over

    def checks(self) -> dict[str, dict[str, Any]]:
        if self._checks is None:
            if not self.finish():
                pytest.fail(f"peer {self.name} ran over {SCENARIO_TIMEOUT_S} s:\n{self.output}")
            self._checks = {}
            if self.proc.returncode != 0:
                pytest.fail(f"peer {self.name} exited {self.proc.returncode}:\n{self.output}")
            lines = self.report.read_text(encoding="utf-8").splitlines() \
                if self.report.exists() else []
            for line in lines:
                facts = json.loads(line)
                self._checks[facts.pop("check")] = facts
        return self._checks

    def kill(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGKILL)

    def check(self, name: str) -> dict[str, Any]:
        checks = self.checks()
        assert name in checks, (f"peer {self.name} did not get to {name!r} (its checks: "
                                f"{sorted(checks)}):\n{self.output}")
        return checks[name]


#: Scenarios started together, a wave once the one before has ended.
WAVES = (("main", "kill", "docs"), ("fault", "ddc", "imu"), ("describe",))


class Scenarios(dict[str, Scenario]):
    """The scenarios by name: the first wave (:data:`WAVES`) starts at once, side by side;
    a later wave when one of its scenarios is first asked for, after every scenario started
    before it has ended: the fault timings are the node's and the emulator's own, but six
    ROS graphs starting at once on two cores starve serve past the boards' request timeouts
    before anything is measured (and a fourth graph beside the first three left the main
    scenario's node 0.17 m of odometry behind its body)."""

    def __init__(self, log_dir: Path) -> None:
        super().__init__({name: Scenario(name, log_dir) for name in WAVES[0]})
        self.log_dir = log_dir

    def __missing__(self, name: str) -> Scenario:
        wave = next(w for w in WAVES if name in w)
        for scenario in list(self.values()):
            scenario.finish()
        for later in wave:
            self[later] = Scenario(later, self.log_dir)
        return self[name]


@pytest.fixture(scope="module")
def scenarios(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Scenario]]:
    running = Scenarios(tmp_path_factory.mktemp("roslog"))
    yield running
    for scenario in running.values():
        scenario.kill()  # whatever it started too, finished or not
        scenario.proc.wait()


def test_joint_states_carry_each_boards_telemetry_in_rad_s_on_its_clock(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["main"].check("joint_states")
    assert facts["names"] == ["FL", "BL", "FR", "BR"]
    # Each truth line is a tick the boards sampled (50 a second while driving 2 s); its
    # message is the one holding that tick's wheel angles, stamped at the board-clock offset
    # most lines hold (a slow wheel keeps its count for a few ticks: the angles alone may
    # name a neighbouring tick's message). A loaded host's node publishes a fraction of the
    # 1 kHz sets (a set is skipped, never delayed), so how many ticks find their message
    # depends on the load. What does not: three or more found, while the wheels turned, and
    # every one holds its tick's speeds exactly (float32, then rad/s).
    assert facts["moving_lines"] >= 20
    assert facts["found"] >= 3 and facts["equal_moving"] >= 1, facts
    assert facts["equal_left"] == facts["found"] and facts["mismatches"] == [], facts
    # The right board's sample is its latest at publishing: at most a tick from the left's.
    assert facts["equal_right"] >= 1, facts
    # Stamped on the board's clock, not at arrival: over the lines found by their angles
    # alone, the offset (stamp − board time) holds still from line to line, to within
    # 0.1 ms of a whole number of ticks, at least half the time (it falls when a smaller
    # delay is found, by at most MAX_SLEW of the time passed, and steps when its estimate
    # is refitted; a neighbour's message is a whole tick off); an arrival time moves with
    # every delivery, anywhere within a tick.
    assert facts["offset_step_median_ns"] is not None, facts
    assert facts["offset_step_median_ns"] <= 100_000, facts
    # 1 kHz configured: never two messages for one sample, never faster than the ticks.
    assert facts["distinct_stamps"] == facts["messages"]
    assert facts["increasing"]
    # A tick apart, less what the clock's estimate of the offset may slew (fpgalink.boardclock).
    assert facts["min_gap_ms"] >= (1.0 - MAX_SLEW) - 1e-6


def test_diagnostics_say_how_far_the_published_samples_lag(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["main"].check("sample_age")
    # The age is of a sample the node published: the diagnostics' stamp less the age is a
    # joint_states stamp, to the 0.1 ms the age is given in; how large it is depends on load.
    assert facts["age"].endswith(" ms") and math.isfinite(float(facts["age"].split()[0]))
    assert facts["nearest_stamp_ns"] is not None, facts
    assert facts["nearest_stamp_ns"] <= 50_000 + 1, facts  # half of 0.1 ms, and a float's


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


def test_diagnostics_say_who_each_board_is(scenarios: dict[str, Scenario]) -> None:
    # Board L answers IQ with this host's declaration; R runs the seed's firmware (fpgaemu
    # serve --seed-protocol) and works all the same, its identity unknown.
    from fpgalink.protocol import SEED_PROTOCOL, declarations_digest

    facts = scenarios["kill"].check("identity")
    left, right = facts["board_l"], facts["board_r"]
    assert left["identity"].startswith(f"protocol {declarations_digest()}, firmware 1.1.0")
    assert left["protocol"] == left["host protocol"] == declarations_digest()
    assert right["identity"] == SEED_PROTOCOL and right["protocol"] == ""
    refused = scenarios["kill"].check("identity_refused")
    assert refused["code"] == 10, refused
    errors = [line for line in refused["stderr"] if "error:" in line]
    assert len(errors) == 1 and "board L" in errors[0], refused
    assert "0123456789abcdef" in errors[0] and declarations_digest() in errors[0]


def test_a_killed_board_server_turns_its_status_to_error_and_disables_the_robot(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["kill"].check("kill")
    assert facts["board_l"] == [2, "not answering"]
    # R is untouched: alive, OK; WARN only if the loaded node read R's port too late and
    # serve dropped the bytes nobody read, as a UART does (its telemetry counter's gap).
    assert facts["board_r"] in ([0, "alive"], [1, "alive; messages lost or damaged"])
    level, message = facts["supervision"]
    assert level == 2 and "board L" in message


def test_the_example_session_in_the_docs_runs_as_shown(scenarios: dict[str, Scenario]
                                                       ) -> None:
    scenarios["docs"].checks()  # it ran to the end, exit 0
    printed = scenarios["docs"].output.splitlines()  # the node's log is in a file of its own
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


def test_a_board_restarting_mid_drive_stops_the_robot_and_is_reconfigured(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["fault"].check("restart")
    assert not facts.get("too_slow"), facts
    # A Kp set through ROS at run time, before the restart.
    assert facts["kp_ok"] and facts["kp_ros_before"] == 400.0, facts
    # The node's first ERROR for board L after the restart (published in the callback that
    # noticed it, stamped on the node's clock) already shows the robot stopped: the stop
    # came with the first sign, not later.
    level, message = facts["first_error"]["supervision"]
    assert level == 2 and message.startswith("disabled: stopped:"), facts["first_error"]
    assert facts["restarted_message"].startswith("restarted: reconfiguring"), facts
    # Then alive: OK, or WARN if the loaded node read L's port too late for serve, which
    # dropped what nobody read (a counter gap: lost messages, said).
    assert facts["l_status_after"] in ([0, "alive"], [1, "alive; messages lost or damaged"])
    # On the emulator's clock: board R's enable fell after L's power-cycle, its PWM 0.
    assert facts["r_disabled_after_ms"] is not None and facts["r_disabled_after_ms"] >= 0
    assert facts["r_pwm_when_off"] == [0, 0]
    # Every ROS parameter of L reads back equal from the board afterwards, Kp 400 too.
    assert facts["differing"] == [], facts["differing"]
    assert facts["ros_params"]["Kp_Wheel_PidA"] == facts["board_params"]["Kp_Wheel_PidA"] \
        == 400.0
    assert facts["board_params"]["GetDataPeriodical"] == 1
    # Odometry continuous across the restart (the encoder's reset is not motion); odom and
    # joint_states flowing again; the enable held all along drives again once L is ready.
    # An encoder reset taken as motion jumps by L's wheels' travel since the start (over half
    # a metre at FAULT_AT_S); 5 cm is beyond what the stamps' own jitter makes of a pose
    # (1.3 cm seen once on the 2-core CI machine: after a restart the board's stamp mapping
    # starts again, so two odom stamps can stand closer than the poses' real interval).
    assert facts["odom_worst_jump_m"] < 0.05, (
        facts["odom_worst_jump_m"], f"the odometry around it: {scenarios['fault'].saved}")
    assert facts["odom_after_ok"] > 10 and facts["joints_after_ok"] > 10, facts
    assert facts["x_driven_again"] > 0.1


def test_one_boards_telemetry_stopping_is_an_error_within_100_ms(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["fault"].check("stale")
    assert not facts.get("too_slow"), facts
    level, message = facts["first_error"]["board R"]
    assert level == 2 and message.startswith("telemetry stopped: none for"), message
    # The silence the node judged, on its own running time (a stalled node does not count
    # its own stall), before it said ERROR: within 100 ms.
    assert facts["silent_ms"] <= 100.0, facts
    # That ERROR already shows the robot stopped; board L got the stop (its enable fell
    # after R's telemetry stopped, on the emulator's clock); and it drives again after.
    level, message = facts["first_error"]["supervision"]
    assert level == 2 and message.startswith("disabled: stopped:"), facts["first_error"]
    assert facts["l_disabled_after_ms"] is not None and facts["l_disabled_after_ms"] >= 0
    assert facts["x_driven_again"] > 0.1


def test_odom_after_a_board_restart_follows_the_body(scenarios: dict[str, Scenario]) -> None:
    # Issue 37.13, on the physics body: once the robot drives again after L's restart, odom
    # moves as the body does, within the 2 % docs/robot.md promises on a straight line
    # (measured between two rests, so no timing between odom and the truth counts).
    facts = scenarios["fault"].check("restart_physics")
    assert not facts.get("too_slow"), facts
    assert facts["at_rest"], f"the body never came to rest after L's restart: {facts}"
    assert facts["truth_m"] > 0.4, facts
    assert facts["odom_m"] == pytest.approx(facts["truth_m"], rel=0.02), facts


def test_the_fault_runs_end_cleanly(scenarios: dict[str, Scenario]) -> None:
    for check in ("restart", "stale", "restart_physics"):
        facts = scenarios["fault"].check(check)
        assert facts["node_exit"] == 0 and facts["serve_exit"] == 0, facts
    assert "Traceback" not in scenarios["fault"].output


# --- as diff_drive_controller's users expect (issue 28) -----------------------------------


def test_the_first_cmd_vel_before_its_enable_is_held_and_sent(
        scenarios: dict[str, Scenario]) -> None:
    # One cmd_vel, taken by the node before any enable (it said it holds it), then only
    # enable: the body moved on that one command, and came to rest by cmd_vel_timeout.
    facts = scenarios["ddc"].check("first_cmd_vel")
    assert facts["held"].startswith("command held: the robot is not enabled"), facts
    assert facts["moving_v"] > 0.05
    assert facts["supervision"] == [0, "enabled"]


def test_a_flood_of_non_finite_cmd_vel_is_warned_about_not_logged_per_message(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["ddc"].check("non_finite")
    warnings = facts["warnings"]
    # 3 s of them at up to 100 a second: one warning per 2 s, the next saying how many
    # were not shown; the body never moved.
    assert 1 <= len(warnings) <= 3, warnings
    assert all(w.startswith("cmd_vel ignored: not finite (nan, 0.0)") for w in warnings)
    assert len(warnings) == 1 or "more like it not shown" in warnings[1]
    assert abs(facts["body_v"]) < 0.01


def test_a_publisher_of_the_other_twist_type_is_named(scenarios: dict[str, Scenario]) -> None:
    line = scenarios["ddc"].check("wrong_type")["line"]
    assert "/stamped_teleop publishes geometry_msgs/msg/TwistStamped" in line
    assert "use_stamped_vel:=true" in line
    line = scenarios["ddc"].check("stamped")["line"]
    assert "/peer publishes geometry_msgs/msg/Twist," in line
    assert "use_stamped_vel:=false" in line


def test_use_stamped_vel_drives_on_twist_stamped(scenarios: dict[str, Scenario]) -> None:
    assert scenarios["ddc"].check("stamped")["driven_m"] > 0.1
    assert scenarios["ddc"].check("stamped_node_exit")["code"] == 0


def test_odom_to_base_link_on_tf_is_the_odometry_at_its_stamp(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["ddc"].check("tf")
    # One transform per odom message, odom → base_link, the same pose at the same stamp.
    assert facts["frames"] == [["odom", "base_link"]]
    assert facts["tf_messages"] >= 50 and facts["pairs"] >= 50, facts
    assert facts["equal"] == facts["pairs"], facts


def test_without_tf2_msgs_the_node_says_so_once_and_runs(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["ddc"].check("stamped")  # that node could not import tf2_msgs
    assert len(facts["no_tf_lines"]) == 1, facts
    assert "fpgalink-ros2 --install-tf2" in facts["no_tf_lines"][0]
    assert facts["tf_messages"] == 0 and facts["driven_m"] > 0.1


def test_without_require_enable_cmd_vel_alone_drives_and_no_deadman_lapses(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["ddc"].check("no_enable")
    assert facts["ok"] and facts["reason"] == "", facts
    # Driven on cmd_vel alone (the test waited for it), at rest after it stopped, and a
    # second later (twice the deadman time, nothing on enable) not stopped by the deadman
    # (WARN "the enable was not renewed"): still enabled, unless a loaded machine's own
    # fault (its watchdog, late telemetry: ERROR) stopped it meanwhile.
    level, message = facts["supervision"]
    assert "not renewed" not in message and facts["deadman_lines"] == [], facts
    if level == 0:
        assert message == "enabled" and facts["enabled"] == {"L": True, "R": True}, facts
    else:
        assert level == 2 and message.startswith("disabled: stopped:"), facts
    assert scenarios["ddc"].check("node_exit")["code"] == 0
    assert scenarios["ddc"].check("serve_exit")["code"] == 0


def test_a_bad_ros_args_value_at_start_exits_2_with_one_line(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["ddc"].check("bad_values")
    expected = {"cmd_vel_timeout:=-1.0": ("cmd_vel_timeout", "Min: 0.05, Max: 10.0"),
                "joint_state_rate:=fast": ("joint_state_rate", "expecting type 'DOUBLE'"),
                "L.Kp_Wheel_Pid.A:=-5.0": ("L.Kp_Wheel_Pid.A", "must be a float ≥ 0"),
                "linear.x.max_deceleration:=0.5": ("linear.x.max_deceleration",
                                                   "takes a finite number < 0")}
    for value, (name, range_text) in expected.items():
        result = facts[value]
        assert result["code"] == 2, (value, result)
        assert len(result["stderr"]) == 1, (value, result)
        line = result["stderr"][0]
        assert line.startswith("fpgalink-ros2: error: --ros-args -p: ") and name in line \
            and range_text in line, line


def test_joint_states_are_reliable_by_default_and_best_effort_on_request(
        scenarios: dict[str, Scenario]) -> None:
    # A reliable subscriber (robot_state_publisher's) matches only a reliable publisher.
    facts = scenarios["ddc"].check("joint_states_qos")
    assert facts["reliable"] > 20 and facts["best_effort"] > 20, facts
    facts = scenarios["ddc"].check("stamped")  # that node: joint_states_best_effort:=true
    assert facts["reliable_joints"] == 0 and facts["best_effort_joints"] > 20, facts


def test_another_node_of_the_same_name_is_warned_about(scenarios: dict[str, Scenario]) -> None:
    lines = scenarios["ddc"].check("name_clash")["lines"]
    assert len(lines) == 1 and lines[0].startswith("another node is named /fpgalink"), lines


def test_a_p_value_for_no_parameter_of_the_node_is_said(scenarios: dict[str, Scenario]) -> None:
    lines = scenarios["ddc"].check("unknown_parameter")["lines"]
    assert len(lines) == 1 and lines[0].startswith(
        "-p cmd_vel_timout: this node has no such parameter: ignored (did you mean "
        "cmd_vel_timeout"), lines


def test_kinematics_are_ros_parameters_set_at_start_and_at_run_time(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["ddc"].check("kinematics")
    # The robot file's by default (the seed's 0.66 m track, 0.2 m wheels, χ 1.65 on gravel).
    assert (facts["separation"], facts["radius"]) == (0.66, 0.2)
    assert facts["chi"] > 1.0
    assert facts["chi_ok"] and facts["chi_reason"] == "", facts
    # χ doubled: the same turn asks twice the wheel speed difference (the references the
    # boards hold, deg/s: 0.1 rad/s · χ·B/2 / r ≈ 15.6 deg/s before).
    assert facts["before"] > 5.0
    assert facts["after"] / facts["before"] == pytest.approx(2.0, rel=0.01), facts
    # -p wheel_separation:=0.7 at start: taken, not ignored.
    assert scenarios["ddc"].check("stamped")["separation"] == 0.7


def test_the_emulated_bodys_imu_is_published_on_imu_data(
        scenarios: dict[str, Scenario]) -> None:
    rest = scenarios["imu"].check("imu_rest")
    assert rest["frame_id"] == "ImuALink"
    # 50 Hz on a schedule: never faster, however late the node ran (fewer on a loaded
    # machine, which is no fault of the IMU's).
    assert 0 < rest["stamp_rate_hz"] <= rest["rate_hz"] * 1.05
    assert rest["orientation_covariance"] == -1.0  # a 6-axis IMU gives no orientation
    assert rest["gyro_variance"] > 0 and rest["accel_variance"] > 0
    assert math.isclose(rest["az"], 9.81, abs_tol=0.3) and abs(rest["ax"]) < 0.3
    assert abs(rest["gz"]) < math.radians(2)
    turning = scenarios["imu"].check("imu_turning")
    assert turning["samples"] >= 25
    assert turning["truth_omega"] > 0.1
    assert math.isclose(turning["gz"], turning["truth_omega"], rel_tol=0.2, abs_tol=0.03)
    assert scenarios["imu"].check("imu_node_exit")["code"] == 0


# --- as robot_state_publisher, RViz and a diff_drive_controller configuration expect ------


def test_robot_description_is_the_urdf_latched_with_the_joint_states_names(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["describe"].check("describe")
    # A subscriber that came after the node got it (transient local), equal to the
    # parameter; its wheels' joints are named as joint_states names them, here renamed
    # with left_wheel_names/right_wheel_names.
    assert facts["topic_equals_parameter"], facts
    renamed = ["left_front", "left_back", "right_front", "right_back"]
    assert facts["joint_names"] == renamed
    assert sorted(facts["urdf_moving_joints"]) == sorted(renamed)
    assert facts["wheel_names"] == [renamed[:2], renamed[2:]]


def test_tf_static_carries_the_urdfs_fixed_joints_with_the_namespace_prefix(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["describe"].check("describe")
    fixed = facts["urdf_fixed"]
    assert {j["child"] for j in fixed} == {"ImuALink", "laser"}
    static = {t["child"]: t for t in facts["static"]}
    assert set(static) == {f"bot/{j['child']}" for j in fixed}
    for joint in fixed:
        transform = static[f"bot/{joint['child']}"]
        assert transform["parent"] == f"bot/{joint['parent']}"
        assert transform["xyz"] == pytest.approx(joint["xyz"], abs=1e-9)
        assert transform["roll_pitch_free"]
        assert transform["yaw"] == pytest.approx(joint["rpy"][2], abs=1e-9)
    # In namespace /bot, as diff_drive_controller's tf_frame_prefix_enable does.
    assert facts["odom_frames"] == ["bot/odom", "bot/base_link"]


def test_twist_covariance_diagonal_is_a_parameter(scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["describe"].check("describe")
    assert facts["twist_covariance"] == [0.01, 0.02, 1e6, 1e6, 1e6, 0.03]
    bad = scenarios["describe"].check("describe_bad_values")
    for value, name in (("pose_covariance_diagonal:=[1.0,2.0]", "pose_covariance_diagonal"),
                        ("left_wheel_names:=[only_one]", "left_wheel_names")):
        assert bad[value]["code"] == 2, bad[value]
        assert len(bad[value]["stderr"]) == 1, bad[value]
        assert bad[value]["stderr"][0].startswith(
            f"fpgalink-ros2: error: --ros-args -p: {name}: "), bad[value]


def test_velocity_limits_are_parameters_and_cmd_vel_out_says_what_was_driven(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["describe"].check("limits")
    # 0.3 m/s asked with linear.x.max_velocity 0.1: driven at 0.1, and said so.
    assert facts["out_v"] == pytest.approx(0.1, abs=1e-9)
    assert facts["out_frame"] == "bot/base_link"
    assert 0.05 < facts["fastest_odom_v"] <= 0.1 + 0.005, facts
    # Never above the robot file's limit.
    assert facts["too_fast_ok"] is False and "angular.z.max_velocity" in \
        facts["too_fast_reason"], facts
    # The sides' radius multipliers, at run time, within their range.
    assert facts["multiplier_ok"] and facts["multiplier"] == 1.05, facts
    assert facts["zero_ok"] is False and "right_wheel_radius_multiplier" in \
        facts["zero_reason"], facts


def _rise(samples: list[list[float]], low: float, high: float) -> float:
    """Seconds from the last sample at or below ``low`` to the first at or above ``high``
    after it."""
    start = max(i for i, (_, v) in enumerate(samples) if v <= low)
    end = next(i for i in range(start, len(samples)) if samples[i][1] >= high)
    return samples[end][0] - samples[start][0]


def _steepest(samples: list[list[float]], window: float) -> float:
    """The largest |change of speed| per second over any stretch of at least ``window``
    seconds (stamps on the emulator's clock)."""
    steepest = 0.0
    for i, (t0, v0) in enumerate(samples):
        for t1, v1 in samples[i + 1:]:
            if t1 - t0 >= window:
                steepest = max(steepest, abs(v1 - v0) / (t1 - t0))
                break
    return steepest


def test_a_step_on_cmd_vel_becomes_a_ramp_at_max_acceleration(
        scenarios: dict[str, Scenario]) -> None:
    # linear.x.max_acceleration 0.2 m/s² given with -p: a step to 0.3 m/s (0.1 after
    # max_velocity), then to 0; 0.5 set at run time, the step again. Each a ramp: cmd_vel_out
    # says what each control step drove, stamped at its samples (the boards' clock, as the
    # limiter's time step), and the wheels' measured speed (odom) follows no faster. A
    # loaded host slows a ramp (a step is at most 0.1 s), never speeds it.
    facts = scenarios["describe"].check("ramps")
    slopes: dict[str, list[float]] = {}
    for phase, acceleration, start, end in (("up", 0.2, 0.0, 0.1), ("down", 0.2, 0.1, 0.0),
                                            ("up_again", 0.5, 0.0, 0.1)):
        out, odom = facts[phase]["out"], facts[phase]["odom"]
        assert out[-1][1] == pytest.approx(end, abs=1e-9), (phase, out)
        assert len({v for _, v in out if 0.0 < v < 0.1}) >= 3, (phase, out)  # not a jump
        # Never faster than the limit, step by step: by at most a × 0.1 s, and at most a
        # between stamps (which may be as close as 75 % of their samples' spacing while
        # the board clock's mapping settles: fpgalink.boardclock).
        speeds = [start, *(v for _, v in out)]
        assert max(abs(b - a) for a, b in itertools.pairwise(speeds)) \
            <= acceleration * 0.1 + 1e-9, (phase, out)
        slopes[phase] = [abs(v1 - v0) / (t1 - t0)
                         for (t0, v0), (t1, v1) in itertools.pairwise(out)]
        assert max(slopes[phase]) <= acceleration / 0.75 + 1e-6, (phase, out)
        # The wheels (odom, on the same clock): no faster (a quarter more for the PID
        # catching up), and a ramp.
        assert _steepest(odom, 0.1) <= 1.25 * acceleration / 0.75 + 0.02, (phase, odom)
        if end > start:
            assert _rise(odom, 0.01, 0.09) >= 0.75 * 0.8 * 0.08 / acceleration, (phase, odom)
    # The run-time set: taken (the steps climb at 0.5 m/s², above what 0.2 allows), read
    # back; a deceleration of the wrong sign refused, saying so.
    assert statistics.median(slopes["up_again"]) > 0.2 / 0.75, slopes
    assert facts["set_ok"] and facts["read_back"] == 0.5, facts
    assert facts["bad_ok"] is False and facts["bad_reason"].startswith(
        "linear.x.max_deceleration takes a finite number < 0"), facts


def test_the_emulated_robot_publishes_clock_and_use_sim_time_stamps_on_it(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["describe"].check("clock")
    assert facts["clocks"] > 20 and facts["increasing"]
    # The emulator's time since it started, not the host's (seconds since 1970).
    assert 0 < facts["last_clock_s"] < 3600
    assert abs(facts["joint_stamp_s"] - facts["last_clock_s"]) < 1.0, facts
    assert scenarios["describe"].check("describe_node_exit")["code"] == 0


def test_bag_records_the_nodes_inputs_as_received_and_its_outputs_as_published(
        scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["describe"].check("bag")
    assert facts["mcap"], facts
    # Read back with rosbags, each message deserialised by rclpy into the type the bag names.
    types = facts["types"]
    assert types["/bot/cmd_vel"] == "geometry_msgs/msg/Twist"
    assert types["/bot/joint_states"] == "sensor_msgs/msg/JointState"
    assert types["/tf"] == types["/tf_static"] == "tf2_msgs/msg/TFMessage"
    assert types["/bot/cmd_vel_out"] == "geometry_msgs/msg/TwistStamped"
    assert types["/diagnostics"] == "diagnostic_msgs/msg/DiagnosticArray"
    counts = facts["counts"]
    assert counts["/bot/robot_description"] == counts["/tf_static"] == 1
    # The inputs as they came: the peer's 0.3 m/s (beyond the limit) and its stops.
    assert facts["cmd_vel_values"] == [0.0, 0.3]
    assert counts["/bot/cmd_vel"] > 10 and counts["/bot/cmd_vel_out"] > 10
    # The outputs as published: every joint_states the peer received is in the bag, and
    # one /tf per odom.
    assert facts["peer_joint_states"] > 20
    assert facts["peer_joint_states_in_bag"] == facts["peer_joint_states"]
    assert counts["/tf"] == counts["/bot/odom"] >= counts["/bot/joint_states"] - 1


def test_with_lifecycle_the_node_is_managed(scenarios: dict[str, Scenario]) -> None:
    facts = scenarios["describe"].check("lifecycle")
    assert facts["unconfigured"] == "unconfigured"
    # Its ports not there yet: configure fails, says why, and is asked again later.
    assert facts["configure_without_boards"] is False, facts
    assert facts["after_failed_configure"] == "unconfigured", facts
    assert facts["not_reached"], facts
    # configure opens the boards and declares their parameters, publishing nothing yet.
    assert facts["configure"] and facts["configured"] == "inactive", facts
    assert facts["board_parameters"] >= 19, facts
    assert facts["joints_before_activate"] == 0, facts
    # cleanup: unconfigured, and configured again (every parameter declared anew).
    assert facts["cleanup"] and facts["cleaned_up"] == "unconfigured", facts
    assert facts["configure_again"] and facts["configured_again"] == "inactive", facts
    assert facts["board_parameters_again"] == facts["board_parameters"], facts
    # activate: joint_states, odom, and cmd_vel drives.
    assert facts["activate"] and facts["active"] == "active", facts
    assert facts["driven_v"] > 0.05
    # deactivate: nothing published after it, commands ignored, the boards disabled.
    assert facts["deactivate"] and facts["inactive"] == "inactive", facts
    assert facts["joints_after_deactivate"] == 0 and facts["stamps_after_deactivate"] == 0
    # activate again: its tasks run again (they were cancelled at once before the fix).
    assert facts["reactivate"] and facts["joints_after_reactivate"] > 0, facts
    # shutdown ends the process cleanly.
    assert facts["shutdown"] and facts["exit"] == 0, facts


def test_a_configure_that_failed_after_declaring_parameters_can_be_asked_again(
        scenarios: dict[str, Scenario]) -> None:
    # A bad -p of a board parameter fails configure after the node's own parameters were
    # declared; the second configure fails for the same reason (before, on the parameters
    # the first had left: "Parameter(s) already declared").
    facts = scenarios["ddc"].check("configure_again")
    assert facts["configures"] == [False, False] and facts["state"] == "unconfigured", facts
    first, second = facts["errors"][:2]
    assert first == second and first.startswith("configure: L.Kp_Wheel_Pid.A: "), facts
    assert facts["shutdown"] and facts["exit"] == 0, facts
