"""A ROS 2 peer written with plain rclpy (nothing of the node's code): it starts
``fpgaemu serve`` and ``fpgalink-ros2`` as processes, talks to the node over ROS, reads what
really happened from the emulator's truth endpoint, and prints one JSON line per check.

    python -m tests.ros2.peer main|kill      (inside tests/ros2/netns.sh: loopback only)

``main``: joint_states against the boards' telemetry, cmd_vel against the body, goal_pose,
the enable deadman, SetParameters. ``kill``: one board's serving process killed. ``imu``:
the node on the emulated robot in its own process (MuJoCo body): ``imu/data`` at rest and
turning, against the node's ``truth``.
Exit 0 when it ran to the end (the checks' verdicts are in the JSON, for the test to assert).
"""

from __future__ import annotations

import itertools
import json
import math
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Bool

PATIENCE = 30.0
NODE = "fpgalink"


def report(check: str, **facts: Any) -> None:
    print(json.dumps({"check": check, **facts}), flush=True)


def float32(value: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", value))[0])


class Truth:
    """The emulator's truth endpoint, read in a thread: every line, in order."""

    def __init__(self, url: str) -> None:
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        self._sock = socket.create_connection((host, int(port)), timeout=PATIENCE)
        self.lines: list[dict[str, Any]] = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        stream = self._sock.makefile("r")
        for line in stream:
            self.lines.append(json.loads(line))

    @property
    def latest(self) -> dict[str, Any]:
        return self.lines[-1]

    def close(self) -> None:
        self._sock.close()


class Process:
    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=None, text=True)

    def ready_lines(self, count: int) -> list[list[str]]:
        assert self.proc.stdout is not None
        lines: list[list[str]] = []
        while len(lines) < count:
            line = self.proc.stdout.readline()
            if not line:
                raise RuntimeError(f"{self.proc.args!r} ended before it was ready")
            lines.append(line.split())
        return lines

    def stop(self, sig: int = signal.SIGTERM) -> int | None:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                return self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        return self.proc.wait(10)


class Peer(Node):
    def __init__(self, namespace: str = "") -> None:
        super().__init__("peer", namespace=namespace)
        self.joints: list[tuple[int, list[float], float]] = []  # stamp ns, velocity, arrival
        self.joint_names: list[str] = []
        self.odom: list[Odometry] = []
        self.diagnostics: list[DiagnosticArray] = []
        self.create_subscription(JointState, "joint_states", self._on_joints,
                                 qos_profile_sensor_data)
        self.create_subscription(Odometry, "odom", self.odom.append, 10)
        self.create_subscription(DiagnosticArray, "diagnostics", self.diagnostics.append, 10)
        self.enable = self.create_publisher(Bool, "enable", 10)
        self.cmd = self.create_publisher(Twist, "cmd_vel", 10)
        self.goal = self.create_publisher(PoseStamped, "goal_pose", 10)
        self.set_client = self.create_client(SetParameters, f"{NODE}/set_parameters")
        self.get_client = self.create_client(GetParameters, f"{NODE}/get_parameters")

    def _on_joints(self, message: JointState) -> None:
        stamp = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        self.joints.append((stamp, list(message.velocity), time.monotonic()))
        self.joint_names = list(message.name)

    def spin_for(self, seconds: float, each: Any = None) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if each is not None:
                each()
            rclpy.spin_once(self, timeout_sec=0.01)

    def spin_until(self, predicate: Any, what: str, each: Any = None,
                   timeout: float = PATIENCE) -> None:
        end = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > end:
                raise TimeoutError(f"timed out after {timeout} s waiting for {what}")
            if each is not None:
                each()
            rclpy.spin_once(self, timeout_sec=0.01)

    def hold_enable(self) -> None:
        self.enable.publish(Bool(data=True))

    def drive(self, v: float, omega: float) -> None:
        message = Twist()
        message.linear.x, message.angular.z = v, omega
        self.cmd.publish(message)
        self.hold_enable()

    def call(self, client: Any, request: Any) -> Any:
        if not client.wait_for_service(timeout_sec=PATIENCE):
            raise TimeoutError(f"service {client.srv_name} not there")
        future = client.call_async(request)
        rclpy.spin_until_future_complete(self, future, timeout_sec=PATIENCE)
        return future.result()

    def set_double(self, name: str, value: float) -> tuple[bool, str]:
        return self._set(name, ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                              double_value=value))

    def set_int(self, name: str, value: int) -> tuple[bool, str]:
        return self._set(name, ParameterValue(type=ParameterType.PARAMETER_INTEGER,
                                              integer_value=value))

    def _set(self, name: str, value: ParameterValue) -> tuple[bool, str]:
        request = SetParameters.Request()
        request.parameters = [ParameterMsg(name=name, value=value)]
        result = self.call(self.set_client, request).results[0]
        return bool(result.successful), str(result.reason)

    def get_double(self, name: str) -> float:
        request = GetParameters.Request()
        request.names = [name]
        return float(self.call(self.get_client, request).values[0].double_value)


def start_node(ports: dict[str, str], *ros_args: str) -> Process:
    node = Process(sys.executable, "-m", "fpgalink.ros2",
                   *(f"--port={name}={url}" for name, url in ports.items()),
                   "--ros-args", *ros_args)
    return node


def main_scenario(peer: Peer) -> None:
    # The kinematic body: these checks are of the node's plumbing, against a body whose
    # motion odometry describes exactly (the imu scenario has the physics body).
    serve = Process(sys.executable, "-m", "fpgaemu", "serve", "--robot", "--pty",
                    "--surface", "gravel", "--body", "kinematic")
    ready = {line[1]: line[2] for line in serve.ready_lines(3)}
    truth = Truth(ready.pop("truth"))
    # This scenario checks what holds when nothing goes wrong. On a loaded machine the
    # served emulator may deliver a board's telemetry tens of ms late, which the node's
    # default (50 periods) rightly takes for a fault: here the limit is 1 s. The faults
    # themselves are the fault scenario's.
    node = start_node(ready, "-p", "joint_state_rate:=1000.0",
                      "-p", "telemetry_timeout_periods:=1000")
    started = time.monotonic()
    try:
        peer.spin_until(lambda: len(peer.joints) > 20, "joint_states")
        report("discovery", first_joint_states_s=peer.joints[0][2] - started)

        # cmd_vel: the body moves, odometry follows it.
        peer.spin_for(2.0, lambda: peer.drive(0.2, math.radians(10)))
        peer.spin_for(1.0, lambda: peer.drive(0.0, 0.0))
        peer.spin_until(lambda: abs(truth.latest["v"]) < 1e-3, "the body at rest",
                        lambda: peer.drive(0.0, 0.0))
        peer.spin_for(0.3, lambda: peer.drive(0.0, 0.0))
        true, odom = truth.latest, peer.odom[-1].pose.pose
        theta = 2 * math.atan2(odom.orientation.z, odom.orientation.w)
        report("cmd_vel", truth_x=true["x"], truth_y=true["y"], truth_theta=true["theta"],
               distance=true["distance"], odom_x=odom.position.x, odom_y=odom.position.y,
               odom_theta=theta)

        # joint_states: each JointState's wheel speeds are one TM's speeds, in rad/s, stamped
        # with that TM's board time plus one fixed offset. The truth stream gives (board time,
        # speeds) of the boards' latest tick 50 times a second.
        peer.joints.clear()
        first_truth = len(truth.lines)
        peer.spin_for(2.0, lambda: peer.drive(0.1, math.radians(-15)))
        report("joint_states", **_match_joint_states(peer, truth.lines[first_truth:]))
        peer.spin_for(1.0, lambda: peer.drive(0.0, 0.0))

        # goal_pose: the robot drives there.
        goal = PoseStamped()
        goal.header.frame_id = "odom"
        goal.pose.position.x = truth.latest["x"] + 0.4
        goal.pose.position.y = truth.latest["y"] - 0.2
        goal.pose.orientation.w = 1.0
        peer.goal.publish(goal)
        target = (goal.pose.position.x, goal.pose.position.y)
        sent = [time.monotonic()]

        def hold_goal() -> None:
            # Topics have no order between them: a stop on cmd_vel still in flight when the
            # goal went out arrives after it and cancels it, as a teleop command must. A
            # robot standing still away from the goal has no goal: send it again.
            peer.hold_enable()
            latest = truth.latest
            if (abs(latest["v"]) < 1e-3 and abs(latest["omega"]) < 1e-3
                    and math.dist(target, (latest["x"], latest["y"])) > 0.1
                    and time.monotonic() - sent[0] > 1.0):
                peer.goal.publish(goal)
                sent[0] = time.monotonic()

        peer.spin_until(lambda: math.dist(target, (truth.latest["x"], truth.latest["y"])) < 0.06
                        and abs(truth.latest["v"]) < 1e-3, "the goal reached", hold_goal,
                        timeout=60)
        report("goal_pose", goal_x=target[0], goal_y=target[1], truth_x=truth.latest["x"],
               truth_y=truth.latest["y"])

        # SetParameters: confirmed by the board, or refused with the reason.
        name = "L.Kp_Wheel_Pid.A"
        ok, reason = peer.set_double(name, 400.0)
        peer.spin_for(0.2)
        on_board = truth.latest["boards"]["L"]["params"]["Kp_Wheel_PidA"]
        bad_ok, bad_reason = peer.set_double(name, -1.0)
        peer.spin_for(0.2)
        after = peer.get_double(name)
        silence_ok, silence_reason = peer.set_int("L.GetDataPeriodical", 0)
        report("parameters", ok=ok, reason=reason, on_board=on_board, bad_ok=bad_ok,
               bad_reason=bad_reason, after=after, silence_ok=silence_ok,
               silence_reason=silence_reason,
               streaming=truth.latest["boards"]["L"]["params"]["GetDataPeriodical"],
               board_after=truth.latest["boards"]["L"]["params"]["Kp_Wheel_PidA"])

        # enable: silence stops the wheels. The truth lines after the last `true` say when
        # each board's PWM reached 0, in board time, against its last RE. A stop for another
        # reason meanwhile (a loaded machine's stalled node: its own watchdog report) is not
        # the deadman's: then the experiment is run again, up to three times.
        for _ in range(3):
            peer.spin_for(1.0, lambda: peer.drive(0.15, 0.0))
            driven = {n: {"pwm": [b["pwm_a"], b["pwm_b"]], "enabled": b["enabled"],
                          "now_s": b["now_s"]} for n, b in truth.latest["boards"].items()}
            last_enable = time.monotonic()
            peer.spin_until(lambda: not any(b["enabled"] or b["pwm_a"] or b["pwm_b"]
                                            for b in truth.latest["boards"].values()),
                            "both boards disabled, PWM 0, after the enable stopped")
            host_wait = time.monotonic() - last_enable
            peer.spin_until(lambda: "stopped" in _status(peer, "supervision")[1],
                            "the stop in diagnostics")
            reason = _status(peer, "supervision")[1]
            if "deadman" in reason:
                break
        stopped = {name: {key: board[key] for key in ("enabled", "pwm_a", "pwm_b", "now_s",
                                                       "last_re_s", "disabled_s",
                                                       "disabled_by")}
                   for name, board in truth.latest["boards"].items()}
        report("enable_silence", host_wait_s=host_wait, driven=driven, stopped=stopped,
               reason=reason)
    finally:
        report("node_exit", code=node.stop())
        report("serve_exit", code=serve.stop())
        truth.close()


def _match_joint_states(peer: Peer, lines: list[dict[str, Any]]) -> dict[str, Any]:
    def expected(line: dict[str, Any], board: str) -> list[float]:
        sample = line["boards"][board]
        return [math.radians(float32(sample["speed_a"])),
                math.radians(float32(sample["speed_b"]))]

    by_speeds: dict[tuple[float, ...], list[int]] = {}
    for stamp, velocity, _ in peer.joints:
        by_speeds.setdefault(tuple(velocity[:2]), []).append(stamp)
    votes: dict[int, int] = {}  # candidate offsets, ns, from every speed match
    for line in lines:
        for stamp in by_speeds.get(tuple(expected(line, "L")), []):
            offset = stamp - line["boards"]["L"]["t_us"] * 1000
            votes[offset] = votes.get(offset, 0) + 1
    offset = max(votes, key=lambda o: votes[o]) if votes else 0
    published = {stamp: velocity for stamp, velocity, _ in peer.joints}
    at_stamp = equal_left = equal_right = 0
    for line in lines:
        found = published.get(offset + line["boards"]["L"]["t_us"] * 1000)
        if found is None:
            continue
        velocity = found
        at_stamp += 1
        equal_left += velocity[:2] == expected(line, "L")
        equal_right += velocity[2:] == expected(line, "R")
    stamps = [stamp for stamp, _, _ in peer.joints]
    gaps_ms = [(b - a) / 1e6 for a, b in itertools.pairwise(stamps)]
    moving = sum(1 for line in lines if any(expected(line, "L")))
    return {"truth_lines": len(lines), "moving_lines": moving,
            "offset_votes": votes.get(offset, 0), "at_stamp": at_stamp,
            "equal_left": equal_left, "equal_right": equal_right,
            "messages": len(stamps), "distinct_stamps": len(set(stamps)),
            "increasing": all(g > 0 for g in gaps_ms), "min_gap_ms": min(gaps_ms, default=0),
            "names": peer.joint_names}


def kill_scenario(peer: Peer) -> None:
    left = Process(sys.executable, "-m", "fpgaemu", "serve", "--pty")
    right = Process(sys.executable, "-m", "fpgaemu", "serve", "--pty", "--seed", "1")
    ports = {"L": left.ready_lines(1)[0][2], "R": right.ready_lines(1)[0][2]}
    # In a namespace, with a board parameter given on the command line: set on the board.
    node = start_node(ports, "-r", "__ns:=/bot", "-p", "L.Kp_Wheel_Pid.B:=350.0")
    try:
        peer.spin_until(lambda: peer.diagnostics, "diagnostics")
        report("ros_args", namespace=peer.get_namespace(),
               kp_b=peer.get_double("L.Kp_Wheel_Pid.B"),
               kp_a=peer.get_double("L.Kp_Wheel_Pid.A"))
        peer.spin_until(lambda: _status(peer, "supervision") == (0, "enabled"),
                        "the robot enabled", peer.hold_enable)
        left.stop(signal.SIGKILL)
        killed = time.monotonic()
        # Its telemetry stopping is the first sign (ERROR at once), its silence the next.
        peer.spin_until(lambda: _status(peer, "board L") == (2, "not answering")
                        and _status(peer, "supervision")[0] == 2, "ERROR statuses",
                        peer.hold_enable)
        report("kill", after_s=time.monotonic() - killed, board_l=_status(peer, "board L"),
               board_r=_status(peer, "board R"), supervision=_status(peer, "supervision"))
    finally:
        report("node_exit", code=node.stop())
        right.stop()


def _status(peer: Peer, name: str) -> tuple[int, str]:
    if not peer.diagnostics:
        return -1, ""
    for status in peer.diagnostics[-1].status:
        if status.name == f"{NODE}: {name}":
            level = status.level
            return (level[0] if isinstance(level, bytes) else int(level)), str(status.message)
    return -1, ""


def imu_scenario(peer: Peer) -> None:
    imu: list[Imu] = []
    truth: list[Odometry] = []
    peer.create_subscription(Imu, "imu/data", imu.append, qos_profile_sensor_data)
    peer.create_subscription(Odometry, "truth", truth.append, 10)
    node = start_node({})  # no port: the emulated robot in the node's process
    try:
        peer.spin_until(lambda: len(imu) >= 50, "imu/data")
        first = time.monotonic()
        count = len(imu)
        peer.spin_for(2.0)
        rate = (len(imu) - count) / (time.monotonic() - first)
        rest = imu[-50:]
        report("imu_rest", rate_hz=rate, frame_id=rest[-1].header.frame_id,
               orientation_covariance=rest[-1].orientation_covariance[0],
               gyro_variance=rest[-1].angular_velocity_covariance[0],
               accel_variance=rest[-1].linear_acceleration_covariance[0],
               ax=sum(m.linear_acceleration.x for m in rest) / len(rest),
               az=sum(m.linear_acceleration.z for m in rest) / len(rest),
               gz=sum(m.angular_velocity.z for m in rest) / len(rest))
        peer.spin_for(3.0, lambda: peer.drive(0.0, 0.3))  # turning on the spot
        imu.clear()
        truth.clear()
        peer.spin_for(2.0, lambda: peer.drive(0.0, 0.3))
        report("imu_turning", gz=sum(m.angular_velocity.z for m in imu) / max(1, len(imu)),
               truth_omega=sum(t.twist.twist.angular.z for t in truth) / max(1, len(truth)),
               samples=len(imu))
        peer.spin_for(0.5, lambda: peer.drive(0.0, 0.0))
    finally:
        report("imu_node_exit", code=node.stop(signal.SIGINT))


def main() -> None:
    scenario = sys.argv[1]
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rclpy.init()
    peer = Peer(namespace="/bot" if scenario == "kill" else "")
    try:
        {"main": main_scenario, "kill": kill_scenario, "imu": imu_scenario}[scenario](peer)
    finally:
        peer.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    main()
