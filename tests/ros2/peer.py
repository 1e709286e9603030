"""A ROS 2 peer written with plain rclpy (nothing of the node's code): it starts
``fpgaemu serve`` (tests/support/serving.py; at nice -10, as :data:`SERVE_COMMAND` says why)
and ``fpgalink-ros2`` as processes, talks to the node over ROS, reads what really happened
from the emulator's truth endpoint, and writes one JSON line per check to REPORT, a file of
its own: never to the stdout and stderr it shares with the node's and serve's logs, where a
check's line could be glued to a log line.

    python -m tests.ros2.peer main|kill|fault|ddc|imu|describe REPORT   (in tests/ros2/netns.sh)

``main``: joint_states against the boards' telemetry, cmd_vel against the body, goal_pose,
the enable deadman, SetParameters. ``kill``: one board's serving process killed.
``fault``: a board restarting mid-drive, then one board's telemetry stopping. ``ddc``:
what a diff_drive_controller user relies on (issue 28). ``imu``: the node on the emulated
robot in its own process (MuJoCo body): ``imu/data`` at rest and turning, against the
node's ``truth``. ``describe``: in namespace ``/bot``, the emulated robot in the node's
process: robot_description and /tf_static against the URDF, frame prefixes, wheel names,
covariances, limits and cmd_vel_out, /clock and use_sim_time.
Exit 0 when it ran to the end (the checks' verdicts are in the JSON, for the test to assert).
Each serve's log goes beside REPORT.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import math
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Log, ParameterType, ParameterValue
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Bool, String
from tf2_msgs.msg import TFMessage

from fpgalink.protocol.robot import SEED_ROBOT_TOML
from fpgalink.ros2.node import IMU_RATE_HZ
from tests.support import serving
from tests.support.serving import Served

PATIENCE = 30.0
NODE = "fpgalink"


#: Where the checks go (the REPORT argument), and serve's logs beside it.
_REPORT: dict[str, Any] = {}


def report(check: str, **facts: Any) -> None:
    """One check's facts, a JSON line of its own in the report file."""
    with open(_REPORT["path"], "a", encoding="utf-8") as out:
        out.write(json.dumps({"check": check, **facts}) + "\n")


#: Every serve of these scenarios runs ahead of the processes at the ordinary priority (the
#: node, this peer, DDS, other test workers, busy loops): it stands in for boards, which
#: never wait for the host's CPU. A board answers every request, so 0.7 s without a byte is
#: a silence the node must act on (the connection's liveness timeout; the node has no
#: parameter for it, rightly): a serve not scheduled that long while the node set its
#: boards up made the node give up at start ("board silent for 0.702 s", exit 4; once in
#: CI, the kill scenario beside two busy loops and three test workers). At nice -10 a
#: process weighs about nine at nice 0 (9548 against 1024): when it wakes the scheduler runs
#: it well ahead of them, and it keeps the fifth of a core it asks for (its boards are paced
#: to real time) until some 65 nice-0 processes compete for the two cores, long after the
#: node, at nice 0, is starved itself. The node's own stalls are no silence of a board (it
#: reads what waits before it judges): no CPU load short of one that starves the node
#: first makes a board look silent. Raising a priority takes CAP_SYS_NICE (the tests run
#: as root); without it (netns.sh in a user namespace, a container that drops it) ``nice``
#: says in serve's log that it could not and serve runs at nice 0, exposed again: said on
#: this peer's output (:func:`start_serve`).
SERVE_NICE = -10
SERVE_COMMAND = ("nice", "-n", str(SERVE_NICE), *serving.PYTHON_M_FPGAEMU)


def start_serve(*args: str) -> Served:
    """``fpgaemu serve ARGS`` (the tests' one way to start it), its log beside the report,
    at the priority of :data:`SERVE_COMMAND` (said when it could not be had)."""
    served = serving.start_serve(*args, log_dir=_REPORT["logs"], command=SERVE_COMMAND)
    nice, own = os.getpriority(os.PRIO_PROCESS, served.pid), os.getpriority(os.PRIO_PROCESS, 0)
    if nice >= own:  # nice(1) could not raise it (it adds to this process's own)
        print(f"peer: fpgaemu serve {' '.join(args)} runs at nice {nice}, no higher than the "
              f"node's: a loaded machine may starve it past the node's liveness timeout",
              flush=True)
    return served


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
    """A node: its output the peer's own (the checks go to the report file, never there)."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(args, text=True)

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
        #: stamp ns, velocity, position: the messages since joint_states_match began
        self.joint_messages: list[tuple[int, list[float], list[float]]] = []
        self.joint_names: list[str] = []
        self.odom: list[Odometry] = []
        self.diagnostics: list[DiagnosticArray] = []
        self.create_subscription(JointState, "joint_states", self._on_joints,
                                 qos_profile_sensor_data)
        # Deep queues: a busy peer must not lose the messages it checks.
        self.create_subscription(Odometry, "odom", self.odom.append, 1000)
        self.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 100)
        # joint_states again, reliable (as robot_state_publisher subscribes): counted
        self.reliable_joints: list[int] = []  # stamps, ns
        self.create_subscription(JointState, "joint_states", self._on_reliable_joints,
                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.tf: list[TFMessage] = []
        self.create_subscription(TFMessage, "/tf", self.tf.append, 1000)
        self.logs: list[tuple[int, str]] = []  # the node's /rosout: (level, text)
        # As rcl publishes it: transient local, so what a node logs before discovery is
        # delivered too.
        self.create_subscription(Log, "/rosout", self._on_log, QoSProfile(
            depth=1000, durability=DurabilityPolicy.TRANSIENT_LOCAL,
            reliability=ReliabilityPolicy.RELIABLE))
        self.enable = self.create_publisher(Bool, "enable", 10)
        self.enable_sent_at = 0.0
        self.cmd = self.create_publisher(Twist, "cmd_vel", 10)
        self.goal = self.create_publisher(PoseStamped, "goal_pose", 10)
        self.set_client = self.create_client(SetParameters, f"{NODE}/set_parameters")
        self.get_client = self.create_client(GetParameters, f"{NODE}/get_parameters")
        self.list_client = self.create_client(ListParameters, f"{NODE}/list_parameters")

    def _on_log(self, message: Log) -> None:
        if message.name.split(".")[-1] == NODE:
            self.logs.append((int(message.level), str(message.msg)))

    def logged(self, text: str) -> list[str]:
        return [line for _, line in self.logs if text in line]

    def _on_reliable_joints(self, message: JointState) -> None:
        self.reliable_joints.append(_stamp_ns(message.header))

    def _on_joints(self, message: JointState) -> None:
        stamp = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        self.joints.append((stamp, list(message.velocity), time.monotonic()))
        self.joint_messages.append((stamp, list(message.velocity), list(message.position)))
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
        # Taken before the publish: the node cannot have the message sooner, so a wait
        # measured from here is never shorter than the node's, however late this peer runs.
        self.enable_sent_at = time.monotonic()
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

    def set_bool(self, name: str, value: bool) -> tuple[bool, str]:
        return self._set(name, ParameterValue(type=ParameterType.PARAMETER_BOOL,
                                              bool_value=value))

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

    def board_parameters(self, board: str) -> dict[str, float]:
        """Every ROS parameter of ``board`` (``L.Kp_Wheel_Pid.A``), by its board name
        (``Kp_Wheel_PidA``, as the truth stream names it)."""
        listing = ListParameters.Request()
        listing.prefixes = [board]
        listing.depth = 0
        names = [n for n in self.call(self.list_client, listing).result.names
                 if n.startswith(f"{board}.")]
        request = GetParameters.Request()
        request.names = names
        values = self.call(self.get_client, request).values
        out: dict[str, float] = {}
        for name, value in zip(names, values, strict=True):
            number = (value.integer_value if value.type == ParameterType.PARAMETER_INTEGER
                      else value.double_value)
            out["".join(name.split(".")[1:])] = float(number)
        return out


def start_node(ports: dict[str, str], *ros_args: str, own: tuple[str, ...] = ()) -> Process:
    node = Process(sys.executable, "-m", "fpgalink.ros2",
                   *(f"--port={name}={url}" for name, url in ports.items()), *own,
                   "--ros-args", *ros_args)
    return node


def main_scenario(peer: Peer) -> None:
    # The kinematic body: these checks are of the node's plumbing, against a body whose
    # motion odometry describes exactly (the imu scenario has the physics body).
    serve = start_serve("--robot", "--pty", "--surface", "gravel", "--body", "kinematic")
    ready = dict(serve.ready)
    assert serve.truth is not None
    truth = Truth(serve.truth)
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

        def odometry_at_rest() -> bool:
            # A loaded node publishes odometry late (its telemetry waits its turn): compared
            # once it has caught up with the stop, its last messages still, after moving.
            recent = peer.odom[-5:]
            return (len(recent) == 5
                    and all(abs(m.twist.twist.linear.x) < 1e-3
                            and abs(m.twist.twist.angular.z) < 1e-3 for m in recent)
                    and math.hypot(recent[-1].pose.pose.position.x,
                                   recent[-1].pose.pose.position.y) > 0.1)

        peer.spin_until(odometry_at_rest, "the odometry at rest", lambda: peer.drive(0.0, 0.0))
        true, odom = truth.latest, peer.odom[-1].pose.pose
        theta = 2 * math.atan2(odom.orientation.z, odom.orientation.w)
        report("cmd_vel", truth_x=true["x"], truth_y=true["y"], truth_theta=true["theta"],
               distance=true["distance"], odom_x=odom.position.x, odom_y=odom.position.y,
               odom_theta=theta)

        # joint_states: each JointState's wheel angles and speeds are one TM's, in rad and
        # rad/s, stamped with that TM's board time mapped onto ROS time. The truth stream gives
        # the board time, encoder counts and speeds of the boards' latest tick 50 times a
        # second.
        peer.joints.clear()
        peer.joint_messages.clear()
        first_truth = len(truth.lines)
        peer.spin_for(2.0, lambda: peer.drive(0.1, math.radians(-15)))
        report("joint_states", **_match_joint_states(peer, truth.lines[first_truth:]))
        # Diagnostics say how far the published sets lag: a board's "latest sample age" is
        # the diagnostics' own stamp less a joint_states stamp the node published (0.1 ms).
        # This peer may miss that one message (a busy peer's subscriptions drop, the
        # sensor-data one by design): the next diagnostics are tried, up to ten.
        ages = [_sample_age(peer)]
        while len(ages) < 10 and (ages[-1][1] is None or ages[-1][1] > 50_001):
            ages.append(_sample_age(peer))
        report("sample_age", age=ages[-1][0], nearest_stamp_ns=ages[-1][1], tries=len(ages))
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
        # Driven first, as long as that takes: a loaded node may still be recovering from a
        # stop of its own (or the truth stream may be read late), so a fixed second of
        # driving is no proof either way.
        def driven_now() -> dict[str, dict[str, Any]]:
            return {n: {"pwm": [b["pwm_a"], b["pwm_b"]], "enabled": b["enabled"],
                        "now_s": b["now_s"]} for n, b in truth.latest["boards"].items()}

        for _ in range(3):
            peer.spin_for(0.5, lambda: peer.drive(0.15, 0.0))
            peer.spin_until(lambda: all(b["enabled"] and any(b["pwm"])
                                        for b in driven_now().values()),
                            "both boards enabled and driven", lambda: peer.drive(0.15, 0.0))
            driven = driven_now()
            peer.spin_until(lambda: not any(b["enabled"] or b["pwm_a"] or b["pwm_b"]
                                            for b in truth.latest["boards"].values()),
                            "both boards disabled, PWM 0, after the enable stopped")
            host_wait = time.monotonic() - peer.enable_sent_at
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


def _sample_age(peer: Peer) -> tuple[str, int | None]:
    """The next diagnostics' "latest sample age" of board L, and how far (ns) the stamp it
    implies is from the nearest joint_states stamp this peer received."""
    heard = len(peer.diagnostics)
    peer.spin_until(lambda: len(peer.diagnostics) > heard, "diagnostics",
                    lambda: peer.drive(0.1, math.radians(-15)))
    array = peer.diagnostics[-1]
    age: str = next(dict((v.key, v.value) for v in status.values)["latest sample age"]
                    for status in array.status if status.name == f"{NODE}: board L")
    set_ns = _stamp_ns(array.header) - round(float(age.removesuffix(" ms")) * 1e6)
    # Topics have no order between them: that set's joint_states may come after.
    peer.spin_until(lambda: any(stamp >= set_ns - 60_000 for stamp, _, _ in peer.joints),
                    "the set the age is of", lambda: peer.drive(0.1, math.radians(-15)))
    received = [stamp for stamp, _, _ in peer.joints] + peer.reliable_joints
    return age, min((abs(stamp - set_ns) for stamp in received), default=None)


def _match_joint_states(peer: Peer, lines: list[dict[str, Any]]) -> dict[str, Any]:
    """Each truth line's tick found among the published joint_states, and its speeds
    compared.

    The key is the left wheels' angles: the encoder counts the tick's TM carried (the
    truth line's ``position_a``/``_b``), as the node turns them into radians (SPEC §5:
    10 counts per encoder pulse). A key shared by several messages (wheels at rest) names
    none and is left out. A slow wheel keeps its count for a few ticks, so a key may still
    name a neighbouring tick whose own message the node skipped (a loaded node publishes a
    fraction of the sets): that message is a whole tick off the board-clock offset, which
    is constant to the nanosecond once locked. So a line's message is the one holding its
    angles *and* stamped within 0.1 ms of the offset most lines hold. Stamps alone are no
    key: a wheel at a steady speed reads the same M/T value on neighbouring ticks, and the
    stamp-following match this replaces locked onto an offset a whole tick off (its
    "mismatches" were each the node's message for the tick before, found 2026-11-25 by
    logging the node's own t_us beside each stamp: the node was right). The stamps are
    checked apart, on the angles alone: mapped from the board's clock, ``stamp − t_us``
    holds still from line to line, where an arrival time would not."""

    def angles(line: dict[str, Any], board: str) -> tuple[float, float]:
        sample, params = line["boards"][board], line["boards"][board]["params"]
        return (math.tau * sample["position_a"] / (10 * params["IncSenzResA"]),
                math.tau * sample["position_b"] / (10 * params["IncSenzResB"]))

    def expected(line: dict[str, Any], board: str) -> list[float]:
        sample = line["boards"][board]
        return [math.radians(float32(sample["speed_a"])),
                math.radians(float32(sample["speed_b"]))]

    by_angles: dict[tuple[float, ...], list[tuple[int, list[float]]]] = {}
    for stamp, velocity, position in peer.joint_messages:
        by_angles.setdefault(tuple(position[:2]), []).append((stamp, velocity))
    ambiguous = 0
    keyed: list[tuple[dict[str, Any], int, list[float]]] = []  # line, stamp, velocity
    for line in lines:
        messages = by_angles.get(angles(line, "L"), [])
        if len(messages) != 1:
            ambiguous += len(messages) > 1
            continue
        keyed.append((line, *messages[0]))
    offsets = [stamp - line["boards"]["L"]["t_us"] * 1000 for line, stamp, _ in keyed]
    # A step's distance from a whole number of ticks (the board's timer period, as its truth
    # line says): a line keyed to a neighbour's message steps the offset by a tick (found
    # beside two busy loops and a second ROS graph: of 3 and 4 lines found, most were
    # neighbours, the median step exactly 1 ms), which is still the board's clock; an
    # arrival time would land anywhere between.
    tick_ns = keyed[0][0]["boards"]["L"]["params"]["TsTimerPeriod"] * 1_000_000 if keyed else 1
    steps_ns = sorted(abs(d - round(d / tick_ns) * tick_ns)
                      for d in (b - a for a, b in itertools.pairwise(offsets)))
    bins: dict[int, list[int]] = {}
    for offset in offsets:
        bins.setdefault(round(offset / 100_000), []).append(offset)
    held = sorted(bins[max(bins, key=lambda key: len(bins[key]))]) if bins else [0]
    locked_offset = held[len(held) // 2]
    found = equal_left = equal_right = equal_moving = 0
    mismatches: list[dict[str, Any]] = []
    for (line, stamp, velocity), offset in zip(keyed, offsets, strict=True):
        if abs(offset - locked_offset) > 100_000:
            continue
        found += 1
        if velocity[:2] == expected(line, "L"):
            equal_left += 1
            equal_moving += any(velocity[:2])
        else:
            mismatches.append({"line_t_us": line["boards"]["L"]["t_us"], "stamp_ns": stamp,
                               "speeds": expected(line, "L"), "published": velocity[:2]})
        # The right board's sample is its latest when the left's completed the set.
        equal_right += velocity[2:] == expected(line, "R")
    stamps = [stamp for stamp, _, _ in peer.joints]
    gaps_ms = [(b - a) / 1e6 for a, b in itertools.pairwise(stamps)]
    moving = sum(1 for line in lines if any(expected(line, "L")))
    return {"truth_lines": len(lines), "moving_lines": moving, "keyed": len(keyed),
            "found": found, "ambiguous": ambiguous,
            "equal_left": equal_left, "equal_right": equal_right, "equal_moving": equal_moving,
            "mismatches": mismatches,
            "offset_step_median_ns": steps_ns[len(steps_ns) // 2] if steps_ns else None,
            "offset_step_max_ns": steps_ns[-1] if steps_ns else None,
            "messages": len(stamps), "distinct_stamps": len(set(stamps)),
            "increasing": all(g > 0 for g in gaps_ms), "min_gap_ms": min(gaps_ms, default=0),
            "names": peer.joint_names}


def kill_scenario(peer: Peer) -> None:
    left = start_serve("--pty")
    # R runs the seed's firmware, which does not know IQ: its identity is unknown, and it
    # works as L does (docs/protocol.md §8).
    right = start_serve("--pty", "--seed", "1", "--seed-protocol")
    ports = {"L": left.url, "R": right.url}
    # In a namespace, with a board parameter given on the command line: set on the board.
    node = start_node(ports, "-r", "__ns:=/bot", "-p", "L.Kp_Wheel_Pid.B:=350.0")
    try:
        peer.spin_until(lambda: peer.diagnostics, "diagnostics")
        report("ros_args", namespace=peer.get_namespace(),
               kp_b=peer.get_double("L.Kp_Wheel_Pid.B"),
               kp_a=peer.get_double("L.Kp_Wheel_Pid.A"))
        report("identity", board_l=_values(peer, "board L"), board_r=_values(peer, "board R"))
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
        left.stop()  # killed above, unless something failed first: it holds our output
    # A board whose firmware was built from another declaration: the node refuses to
    # start, one line naming both hashes, exit 10 (R, free again, is the seed board).
    other = start_serve("--pty", "--declarations", "0123456789abcdef")
    try:
        ports = {"L": other.url, "R": ports["R"]}
        refused = subprocess.run([sys.executable, "-m", "fpgalink.ros2",
                                  *(f"--port={b}={url}" for b, url in ports.items())],
                                 capture_output=True, text=True, timeout=PATIENCE)
        report("identity_refused", code=refused.returncode,
               stderr=refused.stderr.splitlines())
    finally:
        other.stop()
        right.stop()


#: Emulated seconds at which the fault scenario's first fault comes, doubled on a machine
#: too busy to be driving by then (the times of --fault are fixed when serve starts).
FAULT_AT_S = 8.0
#: A body faster than this never drove the seed robot in these tests: between two odom
#: messages the pose moves at most this much per second of stamp (a lost message is no
#: jump; an encoder reset taken as motion is).
TOP_SPEED = 0.5


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _statuses(array: DiagnosticArray) -> dict[str, tuple[int, str]]:
    out = {}
    for status in array.status:
        level = status.level
        out[str(status.name).removeprefix(f"{NODE}: ")] = (
            level[0] if isinstance(level, bytes) else int(level), str(status.message))
    return out


def _epoch_of(lines: list[dict[str, Any]], t: float) -> float:
    """The host epoch time at which the emulator's clock read ``t`` (the truth stream
    says which host instant each record's boards were advanced to)."""
    line = min(lines, key=lambda line: abs(line["t"] - t))
    return float(line["host_time"]) - (float(line["t"]) - t)


class FaultRun:
    """``fpgaemu serve --robot`` with one fault at a fixed emulated time, the node, and
    the peer driving; ``None`` from :meth:`start` when the machine was too slow to be
    driving before the fault."""

    def __init__(self, peer: Peer, fault: str, at: float,
                 body: tuple[str, ...] = ("--surface", "ideal")) -> None:
        self.peer, self.at = peer, at
        #: messages stamped before this are an earlier run's, arriving late
        self.started_ns = peer.get_clock().now().nanoseconds
        self.serve = start_serve("--robot", "--pty", *body, "--fault", fault)
        ready = dict(self.serve.ready)
        assert self.serve.truth is not None
        self.truth = Truth(self.serve.truth)
        self.node = start_node(ready)

    def driving_before_the_fault(self) -> bool:
        """False when it was not: too slow, or the node gave up at start (a loaded
        machine's emulator not answering its first requests in time: exit 4)."""
        peer, truth = self.peer, self.truth
        peer.spin_until(lambda: len(peer.joints) > 20 or self.node.proc.poll() is not None,
                        "joint_states")
        if self.node.proc.poll() is not None:
            print(f"the node exited {self.node.proc.returncode} at start: again", flush=True)
            return False
        peer.spin_until(lambda: truth.latest["v"] > 0.05
                        and _status(peer, "supervision") == (0, "enabled"),
                        "the robot driving", lambda: peer.drive(0.2, 0.0))
        return bool(truth.latest["t"] < self.at - 1.0)

    def stop(self) -> dict[str, Any]:
        codes = {"node_exit": self.node.stop(), "serve_exit": self.serve.stop()}
        self.truth.close()
        return codes


def fault_scenario(peer: Peer) -> None:
    """A board restarting mid-drive, then (in a second serve) one board's telemetry
    stopping. Each timing is taken on the node's own stamps or the emulator's clock."""
    _fault_run(peer, "restart", _restart_run)
    _fault_run(peer, "stale", _stale_run)
    _fault_run(peer, "restart_physics", _restart_physics_run,
               ("--surface", "gravel", "--body", "mujoco"))


def _fault_run(peer: Peer, check: str, body: Any,
               serve_body: tuple[str, ...] = ("--surface", "ideal")) -> None:
    at = FAULT_AT_S
    for attempt in range(5):  # a loaded machine may stop the robot before the fault
        fault = (f"L:restart={at:g}" if check.startswith("restart")
                 else f"R:tm-loss={at:g}:1")
        run = FaultRun(peer, fault, at, serve_body)
        try:
            peer.odom.clear()
            peer.joints.clear()
            peer.diagnostics.clear()
            if run.driving_before_the_fault():
                facts = body(peer, run)
                facts.update(run.stop(), attempts=attempt + 1, fault=fault)
                if not facts.pop("disturbed"):
                    report(check, **facts)
                    return
                print(f"{check}: the robot was stopped before the fault (a loaded machine's "
                      f"own fault): again", flush=True)
            elif run.node.proc.poll() is None:
                at *= 2
        finally:
            run.stop()
    report(check, too_slow=True)


def _disturbed(lines: list[dict[str, Any]], at: float) -> bool:
    """The robot was not driving just before the fault: another fault (a loaded machine
    starving the emulator's or the node's process) had stopped it, and nothing can be
    measured of this one."""
    before = [line for line in lines if line["t"] < at]
    if not before or not all(board["enabled"] for board in before[-1]["boards"].values()):
        return True
    # Truth lines are 20 ms apart: an enable that fell after the last line before the fault
    # but before the fault itself shows only in the next line's disabled_s (one run saw R
    # disabled 14 ms before L's power cycle).
    after = next((line for line in lines if line["t"] >= at), None)
    return after is not None and any(
        board["disabled_s"] is not None and before[-1]["t"] <= board["disabled_s"] < at
        for board in after["boards"].values())


def _first_error(peer: Peer, board: str, since_ns: int, text: str = ""
                 ) -> tuple[int, dict[str, tuple[int, str]]] | None:
    for array in list(peer.diagnostics):
        statuses = _statuses(array)
        level, message = statuses.get(f"board {board}", (-1, ""))
        stamp = _stamp_ns(array.header)
        if stamp >= since_ns and level == 2 and text in message:
            return stamp, statuses
    return None


def _restart_run(peer: Peer, run: FaultRun) -> dict[str, Any]:
    truth = run.truth
    # A parameter set through ROS at run time, before the restart.
    kp_ok, kp_reason = peer.set_double("L.Kp_Wheel_Pid.A", 400.0)
    params_before = peer.board_parameters("L")
    drive = lambda: peer.drive(0.2, 0.0)  # noqa: E731
    peer.spin_until(lambda: truth.latest["t"] > run.at, "the restart", drive, timeout=60)
    restart_ns = round(_epoch_of(truth.lines, run.at) * 1e9)
    # Driving on (enable held all along): the node must refuse until L is reconfigured,
    # then the enable drives again.
    # "restarted: …" is the status once the restart is known; a silence longer than the
    # liveness timeout (a stalled node) comes first as "heard again: checking whether it
    # restarted".
    peer.spin_until(lambda: _first_error(peer, "L", restart_ns, "restarted:") is not None,
                    "board L's restart in diagnostics", drive)
    peer.spin_until(lambda: _status(peer, "board L")[0] in (0, 1)
                    and _status(peer, "supervision") == (0, "enabled"),
                    "board L no longer ERROR and the robot enabled again", drive, timeout=60)
    ok_ns = _stamp_ns(peer.diagnostics[-1].header)
    l_after = _status(peer, "board L")  # (later a loaded machine may add faults of its own)
    x_again = truth.latest["x"]
    peer.spin_until(lambda: truth.latest["x"] > x_again + 0.1, "driving again", drive)
    peer.spin_for(0.3, drive)
    peer.spin_for(0.5, lambda: peer.drive(0.0, 0.0))

    first = _first_error(peer, "L", restart_ns)
    assert first is not None
    first_ns, at_first = first
    restarted = _first_error(peer, "L", restart_ns, "restarted:")
    assert restarted is not None
    lines = list(truth.lines)
    # R's enable fell after the restart: by the node's RD (or its own watchdog).
    after = [line for line in lines if line["t"] >= run.at]
    r_off = next((line["boards"]["R"] for line in after
                  if not line["boards"]["R"]["enabled"]), None)
    odom = [(_stamp_ns(m.header), m.pose.pose.position.x, m.pose.pose.position.y)
            for m in peer.odom if _stamp_ns(m.header) >= run.started_ns]
    jumps = [math.dist(a[1:], b[1:]) - TOP_SPEED * max(0, b[0] - a[0]) / 1e9
             for a, b in itertools.pairwise(odom)]
    board_now = truth.latest["boards"]["L"]["params"]
    ros_now = peer.board_parameters("L")
    return {
        "disturbed": _disturbed(lines, run.at),
        "kp_ok": kp_ok, "kp_reason": kp_reason,
        "kp_ros_before": params_before.get("Kp_Wheel_PidA"),
        "first_error_after_ms": (first_ns - restart_ns) / 1e6,
        "first_error": at_first,
        "restarted_message": restarted[1]["board L"][1],
        "l_status_after": l_after,
        "ok_after_ms": (ok_ns - restart_ns) / 1e6,
        "r_disabled_after_ms": None if r_off is None or r_off["disabled_s"] is None
        else (r_off["disabled_s"] - run.at) * 1000,
        "r_disabled_by": None if r_off is None else r_off["disabled_by"],
        "r_pwm_when_off": None if r_off is None else [r_off["pwm_a"], r_off["pwm_b"]],
        "ros_params": ros_now, "board_params": board_now,
        "differing": sorted(name for name, value in ros_now.items()
                            if float32(value) != float32(board_now.get(name, math.nan))),
        "odom_messages": len(odom), "odom_worst_jump_m": max(jumps, default=math.inf),
        "odom_worst_jump": _around_worst(odom, jumps, restart_ns),
        "odom_after_ok": sum(1 for stamp, _, _ in odom if stamp > ok_ns),
        "joints_after_ok": sum(1 for stamp, _, _ in peer.joints if stamp > ok_ns),
        "x_driven_again": truth.latest["x"] - x_again,
        "l_enabled_end": truth.latest["boards"]["L"]["enabled"],
    }


def _around_worst(odom: list[tuple[int, float, float]], jumps: list[float], since_ns: int
                  ) -> list[tuple[float, float, float]]:
    """The odom messages around the worst jump: (ms after ``since_ns``, x, y)."""
    if not jumps:
        return []
    worst = jumps.index(max(jumps))
    return [((stamp - since_ns) / 1e6, x, y) for stamp, x, y in odom[max(0, worst - 3):worst + 4]]


def _at_rest(peer: Peer, truth: Truth) -> tuple[float, float, float, float] | None:
    """The wheels brought to rest, the enable held, until the body and odom are still:
    odom's (x, y) and the truth's, where neither moves (no timing between them counts);
    ``None`` when the body never came to rest (a wheel still driven)."""
    def still() -> bool:
        odom = peer.odom[-1].twist.twist if peer.odom else None
        return (abs(truth.latest["v"]) < 1e-3 and abs(truth.latest["omega"]) < 1e-3
                and odom is not None and abs(odom.linear.x) < 1e-3)

    try:
        peer.spin_until(still, "the robot at rest", lambda: peer.drive(0.0, 0.0))
    except TimeoutError:
        return None
    peer.spin_for(0.1, lambda: peer.drive(0.0, 0.0))
    odom = peer.odom[-1].pose.pose.position
    return odom.x, odom.y, truth.latest["x"], truth.latest["y"]


def _restart_physics_run(peer: Peer, run: FaultRun) -> dict[str, Any]:
    """Issue 37.13: on the physics body, odom after L's restart follows the body (it
    counted L's new counters, which the emulator no longer turned: half the motion)."""
    truth = run.truth
    drive = lambda: peer.drive(0.2, 0.0)  # noqa: E731
    peer.spin_until(lambda: truth.latest["t"] > run.at, "the restart", drive, timeout=60)
    peer.spin_until(lambda: truth.latest["t"] > run.at + 0.2
                    and _status(peer, "board L")[0] in (0, 1)
                    and _status(peer, "supervision") == (0, "enabled"),
                    "board L ready and the robot enabled again", drive, timeout=60)
    start = _at_rest(peer, truth)
    end = None
    if start is not None:
        x = truth.latest["x"]
        peer.spin_until(lambda: truth.latest["x"] > x + 0.4, "0.4 m after the restart", drive)
        end = _at_rest(peer, truth)
    facts: dict[str, Any] = {"disturbed": _disturbed(list(truth.lines), run.at),
                             "at_rest": start is not None and end is not None}
    if start is not None and end is not None:
        facts.update(odom_m=math.dist(start[:2], end[:2]), truth_m=math.dist(start[2:], end[2:]),
                     odom_yaw_deg=math.degrees(2 * math.atan2(
                         peer.odom[-1].pose.pose.orientation.z,
                         peer.odom[-1].pose.pose.orientation.w)),
                     truth_yaw_deg=math.degrees(truth.latest["theta"]))
    return facts


def _stale_run(peer: Peer, run: FaultRun) -> dict[str, Any]:
    truth = run.truth
    drive = lambda: peer.drive(0.2, 0.0)  # noqa: E731
    peer.spin_until(lambda: truth.latest["t"] > run.at, "the telemetry loss", drive,
                    timeout=60)
    loss_ns = round(_epoch_of(truth.lines, run.at) * 1e9)
    peer.spin_until(lambda: _first_error(peer, "R", loss_ns, "telemetry") is not None,
                    "board R's telemetry stopped in diagnostics", drive)
    # After the loss both boards enabled again, on the emulator's truth (the diagnostics of
    # a loaded machine may flap with late telemetry of its own meanwhile).
    peer.spin_until(lambda: truth.latest["t"] > run.at + 1.2
                    and all(b["enabled"] for b in truth.latest["boards"].values()),
                    "the robot enabled again after the loss", drive, timeout=60)
    x_again = truth.latest["x"]
    peer.spin_until(lambda: truth.latest["x"] > x_again + 0.1, "driving again", drive)
    peer.spin_for(0.5, lambda: peer.drive(0.0, 0.0))
    first = _first_error(peer, "R", loss_ns, "telemetry")
    assert first is not None
    first_ns, at_first = first
    message = at_first["board R"][1]
    silent_ms = float(message.split("none for ")[1].split(" ms")[0])
    # The last joint_states before the ERROR: stamped on the boards' clock.
    last_joint = max((stamp for stamp, _, _ in peer.joints if stamp < first_ns), default=0)
    after = [line for line in truth.lines if line["t"] >= run.at]
    l_off = next((line["boards"]["L"] for line in after
                  if not line["boards"]["L"]["enabled"]), None)
    return {
        "disturbed": _disturbed(list(truth.lines), run.at),
        "first_error": at_first, "silent_ms": silent_ms,
        "error_after_last_joint_ms": (first_ns - last_joint) / 1e6,
        "error_after_loss_ms": (first_ns - loss_ns) / 1e6,
        "l_disabled_after_ms": None if l_off is None or l_off["disabled_s"] is None
        else (l_off["disabled_s"] - run.at) * 1000,
        "l_disabled_by": None if l_off is None else l_off["disabled_by"],
        "x_driven_again": truth.latest["x"] - x_again,
    }


def _twist(v: float, omega: float) -> Twist:
    message = Twist()
    message.linear.x, message.angular.z = v, omega
    return message


@contextlib.contextmanager
def other_participant(name: str) -> Iterator[Node]:
    """A node in a DDS participant of its own (its own rclpy context)."""
    context = Context()
    rclpy.init(context=context)
    node = Node(name, context=context)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


#: fpgalink-ros2 where ``import tf2_msgs`` fails.
WITHOUT_TF2_MSGS = ("import runpy, sys; sys.modules['tf2_msgs'] = None; "
                    "sys.argv[0] = 'fpgalink-ros2'; "
                    "runpy.run_module('fpgalink.ros2', run_name='__main__')")


def _turn_difference(peer: Peer, truth: Truth) -> float:
    """Turning in place at 0.1 rad/s on cmd_vel for 1.5 s: the median over its last 0.5 s
    of the right side's wheel reference minus the left's as the boards hold them (deg/s, on
    the emulator's truth: what the node asked, whatever the wheels made of it)."""
    start = len(truth.lines)
    peer.spin_for(1.5, lambda: peer.cmd.publish(_twist(0.0, 0.1)))
    lines = truth.lines[start:]
    settled = [line["boards"] for line in lines[len(lines) * 2 // 3:]
               if all(b["enabled"] for b in line["boards"].values())]
    differences = sorted((b["R"]["reference_a"] + b["R"]["reference_b"]
                          - b["L"]["reference_a"] - b["L"]["reference_b"]) / 2
                         for b in settled)
    return differences[len(differences) // 2] if differences else math.nan


def _tf_against_odom(peer: Peer) -> dict[str, Any]:
    """Each /tf transform against the odom message of the same stamp."""
    odom = {_stamp_ns(m.header): m for m in peer.odom}
    pairs = equal = 0
    frames = set()
    for message in peer.tf:
        for transform in message.transforms:
            frames.add((str(transform.header.frame_id), str(transform.child_frame_id)))
            match = odom.get(_stamp_ns(transform.header))
            if match is None:
                continue
            pairs += 1
            t, p = transform.transform, match.pose.pose
            equal += (t.translation.x == p.position.x and t.translation.y == p.position.y
                      and t.translation.z == 0.0 and t.rotation == p.orientation)
    return {"tf_messages": len(peer.tf), "odom_messages": len(peer.odom), "pairs": pairs,
            "equal": equal, "frames": sorted(frames)}


def ddc_scenario(peer: Peer) -> None:
    with contextlib.ExitStack() as exits:
        _ddc(peer, exits)


def _bad_values_at_start(*values: str, ports: dict[str, str] | None = None
                         ) -> dict[str, dict[str, Any]]:
    """Each ``-p VALUE`` given to a node of its own, all at once: the exit code and stderr
    lines of each."""
    own = [f"--port={b}={url}" for b, url in (ports or {}).items()]
    runs = {value: subprocess.Popen([sys.executable, "-m", "fpgalink.ros2", *own,
                                     "--ros-args", "-p", value],
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            for value in values}
    facts = {}
    for value, run in runs.items():
        try:
            _, stderr = run.communicate(timeout=PATIENCE)
        except subprocess.TimeoutExpired:
            run.kill()
            _, stderr = run.communicate()
        facts[value] = {"code": run.returncode, "stderr": stderr.splitlines()}
    return facts


def _bad_values() -> None:
    """A bad ``-p`` at start: exit 2 with one line naming the parameter and its range."""
    report("bad_values", **_bad_values_at_start(
        "cmd_vel_timeout:=-1.0", "joint_state_rate:=fast", "L.Kp_Wheel_Pid.A:=-5.0",
        "linear.x.max_deceleration:=0.5"))


class ConfigureAgain:
    """A ``--lifecycle`` node (in /bad) whose ``-p`` board L refuses, after every node
    parameter was declared: a second configure must fail the same way (it failed on the
    parameters the first left), and the node still shut down cleanly. Its calls go one
    after another while this peer spins for the ddc scenario's own checks."""

    def __init__(self, peer: Peer) -> None:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState, GetState

        self.peer = peer
        self.node = start_node(KINEMATIC, "-r", "__ns:=/bad", "-p", "L.Kp_Wheel_Pid.A:=-5.0",
                               own=("--lifecycle",))
        change = peer.create_client(ChangeState, f"/bad/{NODE}/change_state")
        get = peer.create_client(GetState, f"/bad/{NODE}/get_state")

        def transition(label: str) -> tuple[Any, Any]:
            return change, ChangeState.Request(transition=Transition(label=label))

        self.calls = [transition("configure"), transition("configure"),
                      (get, GetState.Request()), transition("shutdown")]
        self.answers: list[Any] = []

    def start(self) -> None:
        """The first call, once the node's services are there (it started meanwhile)."""
        for client in {id(c): c for c, _ in self.calls}.values():
            if not client.wait_for_service(timeout_sec=PATIENCE):
                raise TimeoutError(f"service {client.srv_name} not there")
        self._next()

    def _next(self, done: Any = None) -> None:
        if done is not None:
            self.answers.append(done.result())
        if len(self.answers) < len(self.calls):
            client, request = self.calls[len(self.answers)]
            client.call_async(request).add_done_callback(self._next)

    def errors(self) -> list[str]:
        return [text for level, text in self.peer.logs
                if level >= 40 and text.startswith("configure: ")]

    def finish(self) -> None:
        facts: dict[str, Any] = {}
        try:
            self.peer.spin_until(lambda: len(self.answers) == len(self.calls)
                                 and len(self.errors()) >= 2,
                                 "the /bad node's transitions, its errors said")
            facts = {"configures": [bool(a.success) for a in self.answers[:2]],
                     "state": str(self.answers[2].current_state.label),
                     "shutdown": bool(self.answers[3].success), "errors": self.errors(),
                     "exit": self.node.proc.wait(PATIENCE)}
        finally:
            self.node.stop(signal.SIGKILL)
            report("configure_again", **facts)


def _ddc(peer: Peer, exits: contextlib.ExitStack) -> None:
    """What a diff_drive_controller user relies on: bad -p values refused at start, a
    lifecycle configure asked again after a failure, the first cmd_vel after enable not
    dropped, a flood of non-finite commands warned about without flooding the log, a
    publisher of the other Twist type named, driving on cmd_vel alone without the enable
    deadman (require_enable false), and TwistStamped on cmd_vel (use_stamped_vel)."""
    configure_again = ConfigureAgain(peer)
    exits.callback(configure_again.node.stop, signal.SIGKILL)
    _bad_values()
    configure_again.start()
    serve = start_serve("--robot", "--pty", "--surface", "ideal")
    ready = dict(serve.ready)
    assert serve.truth is not None
    truth = Truth(serve.truth)
    # As in the main scenario: a loaded machine's late telemetry is not what is tested here.
    patient = ("-p", "telemetry_timeout_periods:=1000")
    # A misspelt -p: said, not silently ignored.
    node = start_node(ready, *patient, "-p", "cmd_vel_timout:=1.0")
    try:
        peer.spin_until(lambda: len(peer.joints) > 20 and peer.diagnostics, "the node up")
        peer.spin_until(lambda: peer.logged("-p cmd_vel_timout"), "the misspelt -p said")
        report("unknown_parameter", lines=peer.logged("-p cmd_vel_timout"))
        # The first cmd_vel, before any enable: held (the node says so), then sent when
        # the enable comes. Nothing else is published on cmd_vel.
        peer.cmd.publish(_twist(0.2, 0.0))
        peer.spin_until(lambda: peer.logged("command held"), "the command held")
        peer.spin_until(lambda: truth.latest["v"] > 0.05, "moving on the held command",
                        peer.hold_enable)
        moving_v = truth.latest["v"]
        peer.spin_until(lambda: abs(truth.latest["v"]) < 1e-3,
                        "at rest after cmd_vel_timeout, the enable held", peer.hold_enable)
        report("tf", **_tf_against_odom(peer))
        report("joint_states_qos", reliable=len(peer.reliable_joints),
               best_effort=len(peer.joints))
        report("first_cmd_vel", moving_v=moving_v, held=peer.logged("command held")[0],
               supervision=_status(peer, "supervision"))

        # A flood of non-finite commands for 3 s: a few warnings, each saying how many
        # like it were not shown.
        before = len(peer.logs)
        nan = _twist(math.nan, 0.0)
        def flood() -> None:
            peer.cmd.publish(nan)
            peer.hold_enable()

        peer.spin_for(3.0, flood)
        peer.spin_for(0.5, peer.hold_enable)
        warnings = [text for _, text in peer.logs[before:] if "not finite" in text]
        report("non_finite", sent_s=3.0, warnings=warnings,
               body_v=truth.latest["v"])

        # A TwistStamped publisher on this node's Twist cmd_vel: named in the log. (From
        # a participant of its own: one participant takes one type per topic.)
        with other_participant("stamped_teleop") as other:
            other.create_publisher(TwistStamped, "cmd_vel", 10)
            peer.spin_until(lambda: peer.logged("publishes geometry_msgs/msg/TwistStamped"),
                            "the other type named", peer.hold_enable)
        report("wrong_type", line=peer.logged("publishes geometry_msgs/msg/TwistStamped")[0])

        # Another node of the node's own name: the node warns.
        with other_participant(NODE):
            peer.spin_until(lambda: peer.logged("another node is named"), "the name clash said",
                            peer.hold_enable)
        report("name_clash", lines=peer.logged("another node is named"))

        # require_enable false: cmd_vel alone drives; silence brings the wheels to rest by
        # cmd_vel_timeout and the robot stays enabled (no deadman).
        ok, reason = peer.set_bool("require_enable", False)
        peer.spin_for(0.7)  # nothing on enable from here: the deadman would have lapsed
        peer.spin_until(lambda: truth.latest["v"] > 0.05, "driving on cmd_vel alone",
                        lambda: peer.cmd.publish(_twist(0.2, 0.0)))
        last_cmd = time.monotonic()
        peer.spin_until(lambda: abs(truth.latest["v"]) < 1e-3, "at rest after cmd_vel stops")
        rest_s = time.monotonic() - last_cmd
        peer.spin_for(1.0)  # twice the deadman time without an enable
        report("no_enable", ok=ok, reason=reason, rest_after_s=rest_s,
               supervision=_status(peer, "supervision"),
               enabled={n: b["enabled"] for n, b in truth.latest["boards"].items()},
               deadman_lines=peer.logged("deadman"))

        # Kinematics as parameters: χ doubled at run time doubles the sides' wheel speed
        # difference asked for the same turn (the boards' references, on the truth).
        chi = peer.get_double("wheel_separation_multiplier")
        turn_before = _turn_difference(peer, truth)
        chi_ok, chi_reason = peer.set_double("wheel_separation_multiplier", 2 * chi)
        turn_after = _turn_difference(peer, truth)
        peer.spin_until(lambda: abs(truth.latest["omega"]) < 1e-3, "at rest after turning")
        report("kinematics", chi=chi, separation=peer.get_double("wheel_separation"),
               radius=peer.get_double("wheel_radius"), chi_ok=chi_ok, chi_reason=chi_reason,
               before=turn_before, after=turn_after)
        configure_again.finish()
    finally:
        report("node_exit", code=node.stop())
    # use_stamped_vel: a node taking TwistStamped; this peer's Twist publisher is named.
    # This node runs where tf2_msgs cannot be imported: it says so, once, and runs.
    peer.logs.clear()
    started_ns = peer.get_clock().now().nanoseconds  # the node before it has ended
    node = Process(sys.executable, "-c", WITHOUT_TF2_MSGS, *(f"--port={name}={url}"
                   for name, url in ready.items()),
                   "--ros-args", "-p", "use_stamped_vel:=true",
                   "-p", "joint_states_best_effort:=true", "-p", "wheel_separation:=0.7",
                   *patient)
    try:
        teleop = exits.enter_context(other_participant("stamped_teleop"))
        stamped = teleop.create_publisher(TwistStamped, "cmd_vel", 10)
        peer.diagnostics.clear()
        peer.spin_until(lambda: peer.diagnostics, "the stamped node up")
        command = TwistStamped()
        command.twist.linear.x = 0.2

        def drive() -> None:
            command.header.stamp = peer.get_clock().now().to_msg()
            stamped.publish(command)
            peer.hold_enable()

        x0 = truth.latest["x"]
        peer.spin_until(lambda: truth.latest["x"] > x0 + 0.1, "driving on TwistStamped", drive)
        peer.spin_until(lambda: peer.logged("publishes geometry_msgs/msg/Twist,"),
                        "the plain Twist publisher named", peer.hold_enable)
        report("stamped", driven_m=truth.latest["x"] - x0,
               separation=peer.get_double("wheel_separation"),
               line=peer.logged("publishes geometry_msgs/msg/Twist,")[0],
               no_tf_lines=peer.logged("tf2_msgs is not installed"),
               reliable_joints=sum(1 for stamp in peer.reliable_joints if stamp > started_ns),
               best_effort_joints=sum(1 for stamp, _, _ in peer.joints if stamp > started_ns),
               tf_messages=sum(1 for m in peer.tf for t in m.transforms
                               if _stamp_ns(t.header) > started_ns))
    finally:
        report("stamped_node_exit", code=node.stop())
        report("serve_exit", code=serve.stop())
        truth.close()


def _status(peer: Peer, name: str) -> tuple[int, str]:
    if not peer.diagnostics:
        return -1, ""
    for status in peer.diagnostics[-1].status:
        if status.name == f"{NODE}: {name}":
            level = status.level
            return (level[0] if isinstance(level, bytes) else int(level)), str(status.message)
    return -1, ""


def _values(peer: Peer, name: str) -> dict[str, str]:
    """The key-values of status ``name`` in the latest diagnostics."""
    for status in peer.diagnostics[-1].status:
        if status.name == f"{NODE}: {name}":
            return {str(v.key): str(v.value) for v in status.values}
    return {}


def imu_scenario(peer: Peer) -> None:
    imu: list[Imu] = []
    truth: list[Odometry] = []
    peer.create_subscription(Imu, "imu/data", imu.append, qos_profile_sensor_data)
    peer.create_subscription(Odometry, "truth", truth.append, 10)
    node = start_node({})  # no port: the emulated robot in the node's process
    try:
        peer.spin_until(lambda: len(imu) >= 100, "imu/data")
        rest = imu[-50:]
        span_s = (_stamp_ns(rest[-1].header) - _stamp_ns(rest[0].header)) / 1e9
        report("imu_rest", rate_hz=IMU_RATE_HZ,
               stamp_rate_hz=(len(rest) - 1) / span_s if span_s > 0 else math.inf,
               frame_id=rest[-1].header.frame_id,
               orientation_covariance=rest[-1].orientation_covariance[0],
               gyro_variance=rest[-1].angular_velocity_covariance[0],
               accel_variance=rest[-1].linear_acceleration_covariance[0],
               ax=sum(m.linear_acceleration.x for m in rest) / len(rest),
               az=sum(m.linear_acceleration.z for m in rest) / len(rest),
               gz=sum(m.angular_velocity.z for m in rest) / len(rest))
        peer.spin_for(3.0, lambda: peer.drive(0.0, 0.3))  # turning on the spot
        imu.clear()
        truth.clear()
        # 25 readings (half a second at 50 Hz; longer on a loaded machine) turning steadily.
        peer.spin_until(lambda: len(imu) >= 25 and len(truth) >= 5, "imu/data turning",
                        lambda: peer.drive(0.0, 0.3))
        report("imu_turning", gz=sum(m.angular_velocity.z for m in imu) / max(1, len(imu)),
               truth_omega=sum(t.twist.twist.angular.z for t in truth) / max(1, len(truth)),
               samples=len(imu))
        peer.spin_for(0.5, lambda: peer.drive(0.0, 0.0))
    finally:
        report("imu_node_exit", code=node.stop(signal.SIGINT))


#: The describe scenario's node: kinematic emulated boards in its own process.
KINEMATIC = {b: f"emu://robot/{b}?surface=ideal&body=kinematic" for b in ("L", "R")}
LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)
TWIST_COVARIANCE = [0.01, 0.02, 1e6, 1e6, 1e6, 0.03]


def _urdf_joints(urdf: str) -> tuple[list[str], list[dict[str, Any]]]:
    """The URDF's moving joints' names, and its fixed joints (parent, child, xyz, rpy)."""
    moving, fixed = [], []
    for joint in ET.fromstring(urdf).iter("joint"):
        if joint.get("type") != "fixed":
            moving.append(str(joint.get("name")))
            continue
        origin = joint.find("origin")
        parent, child = joint.find("parent"), joint.find("child")
        assert origin is not None and parent is not None and child is not None
        fixed.append({"parent": parent.get("link"), "child": child.get("link"),
                      "xyz": [float(v) for v in str(origin.get("xyz")).split()],
                      "rpy": [float(v) for v in str(origin.get("rpy")).split()]})
    return moving, fixed


def _transform(t: Any) -> dict[str, Any]:
    r = t.transform.rotation
    yaw = math.atan2(2 * (r.w * r.z + r.x * r.y), 1 - 2 * (r.y * r.y + r.z * r.z))
    return {"parent": t.header.frame_id, "child": t.child_frame_id,
            "xyz": [t.transform.translation.x, t.transform.translation.y,
                    t.transform.translation.z],
            "yaw": yaw, "roll_pitch_free": abs(r.x) < 1e-9 and abs(r.y) < 1e-9}


def _read_bag(path: Path, peer: Peer) -> dict[str, Any]:
    """The node's --bag read back with rosbags, each message deserialised by rclpy's own
    deserialiser into the type the bag names: topics and counts, the cmd_vel values as
    received, and whether every joint_states stamp this peer received is in it."""
    import importlib

    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader

    def get_message(msgtype: str) -> Any:
        package, _, name = msgtype.split("/")
        return getattr(importlib.import_module(f"{package}.msg"), name)

    counts: dict[str, int] = {}
    types: dict[str, str] = {}
    cmd_vel: set[float] = set()
    joint_stamps: set[int] = set()
    with Reader(path) as reader:
        for connection, _, data in reader.messages():
            message = deserialize_message(data, get_message(connection.msgtype))
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
            types[connection.topic] = connection.msgtype
            if connection.topic == "/bot/cmd_vel":
                cmd_vel.add(message.linear.x)
            elif connection.topic == "/bot/joint_states":
                joint_stamps.add(_stamp_ns(message.header))
    received = {stamp for stamp, _, _ in peer.joints}
    metadata = (path / "metadata.yaml").read_text(encoding="utf-8")
    return {"mcap": "storage_identifier: mcap" in metadata, "counts": counts, "types": types,
            "cmd_vel_values": sorted(cmd_vel),
            "peer_joint_states": len(received),
            "peer_joint_states_in_bag": len(received & joint_stamps)}


def _lifecycle(peer: Peer) -> None:
    """``--lifecycle``: a configure that failed (the boards not there yet) asked
    again; nothing published until activated; cleanup and configure again; commands once
    active, nothing after deactivate, the boards disabled; shutdown ends the process."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState

    change = peer.create_client(ChangeState, f"{NODE}/change_state")
    get = peer.create_client(GetState, f"{NODE}/get_state")

    def state() -> str:
        return str(peer.call(get, GetState.Request()).current_state.label)

    def transition(label: str) -> bool:
        return bool(peer.call(change, ChangeState.Request(
            transition=Transition(label=label))).success)

    peer.joints.clear()
    peer.odom.clear()
    # The node before may still have messages queued in this peer: counted by their stamps.
    started_ns = time.time_ns()
    # Its boards cannot be opened until their robot file is there (the emulator's own
    # robot, the seed's): the first configure fails as for a port that does not exist.
    robot_file = Path(tempfile.mkdtemp(prefix="fpgalink-lifecycle-")) / "robot.toml"
    ports = {b: f"{url}&robot={robot_file}" for b, url in KINEMATIC.items()}
    node = start_node(ports, "-r", "__ns:=/bot", "-p", "telemetry_timeout_periods:=1000",
                      own=("--lifecycle",))
    facts: dict[str, Any] = {}
    try:
        facts["unconfigured"] = state()
        # No boards yet: configure fails, saying so; asked again once they are there.
        facts["configure_without_boards"] = transition("configure")
        facts["after_failed_configure"] = state()
        peer.spin_until(lambda: peer.logged("configure: boards not reached"), "why, said")
        facts["not_reached"] = peer.logged("configure: boards not reached")
        robot_file.write_text(SEED_ROBOT_TOML, encoding="utf-8")
        facts["configure"] = transition("configure")
        facts["configured"] = state()
        listing = ListParameters.Request()
        listing.prefixes = ["L"]
        facts["board_parameters"] = len(peer.call(peer.list_client, listing).result.names)
        facts["joints_before_activate"] = sum(1 for stamp, _, _ in peer.joints
                                              if stamp > started_ns)
        # cleanup withdraws what configure declared; configured again, all is declared anew.
        facts["cleanup"] = transition("cleanup")
        facts["cleaned_up"] = state()
        facts["configure_again"] = transition("configure")
        facts["configured_again"] = state()
        facts["board_parameters_again"] = len(peer.call(peer.list_client,
                                                        listing).result.names)
        facts["activate"] = transition("activate")
        facts["active"] = state()
        peer.spin_until(lambda: peer.odom and _stamp_ns(peer.odom[-1].header) > started_ns
                        and peer.odom[-1].twist.twist.linear.x > 0.05,
                        "driving once active", lambda: peer.drive(0.1, 0.0))
        facts["driven_v"] = peer.odom[-1].twist.twist.linear.x
        facts["deactivate"] = transition("deactivate")
        deactivated_ns = time.time_ns()
        peer.spin_until(lambda: peer.logged("deactivated: boards disabled"), "deactivated said",
                        lambda: peer.drive(0.1, 0.0))
        count = len(peer.joints)
        peer.spin_for(1.0, lambda: peer.drive(0.1, 0.0))  # commands while inactive: ignored
        facts["joints_after_deactivate"] = len(peer.joints) - count
        facts["stamps_after_deactivate"] = sum(1 for stamp, _, _ in peer.joints
                                               if stamp > deactivated_ns)
        facts["inactive"] = state()
        # Activated again: publishing and driving again (a second run of the node's tasks).
        facts["reactivate"] = transition("activate")
        reactivated_ns = time.time_ns()
        peer.spin_until(lambda: peer.odom and _stamp_ns(peer.odom[-1].header) > reactivated_ns
                        and peer.odom[-1].twist.twist.linear.x > 0.05,
                        "driving once active again", lambda: peer.drive(0.1, 0.0))
        facts["joints_after_reactivate"] = sum(1 for stamp, _, _ in peer.joints
                                               if stamp > reactivated_ns)
        facts["shutdown"] = transition("shutdown")

    finally:
        try:
            facts["exit"] = node.proc.wait(PATIENCE)
        except subprocess.TimeoutExpired:
            facts["exit"] = node.stop(signal.SIGKILL)
        shutil.rmtree(robot_file.parent, ignore_errors=True)
        report("lifecycle", **facts)


#: The describe node's linear.x.max_acceleration: given with -p, then set at run time (m/s²).
RAMP_ACCELERATIONS = (0.2, 0.5)


def _ramps(peer: Peer, cmd_vel_out: list[TwistStamped], drive_fast: Any) -> dict[str, Any]:
    """The describe node's steps on cmd_vel as ramps: the step to 0.3 m/s just driven
    (0.1 m/s after linear.x.max_velocity) at the -p max_acceleration, the stop after it,
    and, with another max_acceleration set at run time, a step again. Each as cmd_vel_out
    (what the node drove) and odom (the wheels' measured speed), stamped on the emulator's
    clock; a refused set's reason besides."""
    def stamped(messages: list[Any]) -> list[tuple[float, float]]:
        return [(_stamp_ns(m.header) / 1e9,
                 m.twist.linear.x if isinstance(m, TwistStamped) else m.twist.twist.linear.x)
                for m in messages]

    def stop() -> None:
        peer.cmd.publish(_twist(0.0, 0.0))

    def at_rest() -> bool:
        return bool(cmd_vel_out) and cmd_vel_out[-1].twist.linear.x == 0.0 \
            and abs(peer.odom[-1].twist.twist.linear.x) < 0.005

    def at_top() -> bool:
        return bool(cmd_vel_out) and cmd_vel_out[-1].twist.linear.x >= 0.1 - 1e-9 \
            and peer.odom[-1].twist.twist.linear.x > 0.09

    phases: dict[str, Any] = {}
    marks = [(0, 0)]  # (cmd_vel_out, odom) at each phase's start
    peer.spin_until(at_top, "the first ramp's top", drive_fast)
    marks.append((len(cmd_vel_out), len(peer.odom)))
    peer.spin_until(at_rest, "at rest after the first stop", stop)
    marks.append((len(cmd_vel_out), len(peer.odom)))
    phases["set_ok"], phases["set_reason"] = peer.set_double(
        "linear.x.max_acceleration", RAMP_ACCELERATIONS[1])
    phases["read_back"] = peer.get_double("linear.x.max_acceleration")
    phases["bad_ok"], phases["bad_reason"] = peer.set_double("linear.x.max_deceleration", 0.5)
    marks.append((len(cmd_vel_out), len(peer.odom)))
    peer.spin_until(at_top, "the second ramp's top", drive_fast)
    marks.append((len(cmd_vel_out), len(peer.odom)))
    for name, (start, end) in zip(("up", "down", "up_again"),
                                  ((marks[0], marks[1]), (marks[1], marks[2]),
                                   (marks[3], marks[4])), strict=True):
        phases[name] = {"out": stamped(cmd_vel_out[start[0]:end[0]]),
                        "odom": stamped(peer.odom[start[1]:end[1]])}
    return phases


def describe_scenario(peer: Peer) -> None:
    """What robot_state_publisher, RViz and a diff_drive_controller configuration expect of
    the node (issue 28), in namespace /bot with the emulated robot in its process."""
    cmd_vel_out: list[TwistStamped] = []
    clock: list[tuple[int, float]] = []  # /clock ns, arrival (monotonic)
    peer.create_subscription(TwistStamped, "cmd_vel_out", cmd_vel_out.append, 100)

    def on_clock(message: Clock) -> None:
        clock.append((message.clock.sec * 1_000_000_000 + message.clock.nanosec,
                      time.monotonic()))

    peer.create_subscription(Clock, "/clock", on_clock, 100)
    bag = Path(tempfile.mkdtemp(prefix="fpgalink-describe-")) / "bag"
    node = start_node(KINEMATIC, "-r", "__ns:=/bot",
                      "-p", "left_wheel_names:=[left_front,left_back]",
                      "-p", "right_wheel_names:=[right_front,right_back]",
                      "-p", "publish_limited_velocity:=true",
                      "-p", "linear.x.max_velocity:=0.1",
                      "-p", f"linear.x.max_acceleration:={RAMP_ACCELERATIONS[0]}",
                      "-p", f"twist_covariance_diagonal:={TWIST_COVARIANCE}",
                      "-p", "require_enable:=false", "-p", "use_sim_time:=true",
                      "-p", "telemetry_timeout_periods:=1000", own=(f"--bag={bag}",))
    sent_cmd_vel = 0

    def drive_fast() -> None:
        nonlocal sent_cmd_vel
        peer.cmd.publish(_twist(0.3, 0.0))
        sent_cmd_vel += 1

    try:
        peer.spin_until(lambda: len(peer.joints) > 20 and len(peer.odom) > 20, "the node up")
        # Subscribers that come after the node published: latched, as robot_state_publisher's.
        description: list[str] = []
        static: list[TFMessage] = []

        def on_description(message: String) -> None:
            description.append(message.data)

        peer.create_subscription(String, "robot_description", on_description, LATCHED)
        peer.create_subscription(TFMessage, "/tf_static", static.append, LATCHED)
        peer.spin_until(lambda: description and static, "robot_description and /tf_static")
        request = GetParameters.Request()
        request.names = ["robot_description", "left_wheel_names", "right_wheel_names"]
        values = peer.call(peer.get_client, request).values
        moving, fixed = _urdf_joints(description[0])
        odom = peer.odom[-1]
        report("describe", topic_equals_parameter=description[0] == values[0].string_value,
               urdf_moving_joints=moving, urdf_fixed=fixed, joint_names=peer.joint_names,
               wheel_names=[list(values[1].string_array_value),
                            list(values[2].string_array_value)],
               static=[_transform(t) for m in static for t in m.transforms],
               odom_frames=[odom.header.frame_id, odom.child_frame_id],
               twist_covariance=[odom.twist.covariance[i * 7] for i in range(6)],
               pose_covariance_x=odom.pose.covariance[0])

        # use_sim_time: this node's stamps on the emulator's /clock, not the host's clock.
        peer.spin_until(lambda: len(clock) > 20, "/clock")
        last_clock = clock[-1][0]
        stamp = peer.joints[-1][0]
        report("clock", clocks=len(clock),
               increasing=all(b[0] >= a[0] for a, b in itertools.pairwise(clock)),
               last_clock_s=last_clock / 1e9, joint_stamp_s=stamp / 1e9,
               wall_s=time.time())

        # Limits: 0.3 m/s asked, 0.1 m/s the node's limit: cmd_vel_out says what was
        # driven, and the body goes no faster.
        peer.spin_until(lambda: len(cmd_vel_out) > 10 and peer.odom[-1].twist.twist.linear.x
                        > 0.05, "driving limited", drive_fast)
        peer.spin_for(1.0, drive_fast)
        out = cmd_vel_out[-1]
        fastest = max(m.twist.twist.linear.x for m in peer.odom[-50:])
        too_fast_ok, too_fast_reason = peer.set_double("angular.z.max_velocity", 10.0)
        multiplier_ok, _ = peer.set_double("left_wheel_radius_multiplier", 1.05)
        zero_ok, zero_reason = peer.set_double("right_wheel_radius_multiplier", 0.0)
        report("limits", out_v=out.twist.linear.x, out_frame=out.header.frame_id,
               fastest_odom_v=fastest, too_fast_ok=too_fast_ok,
               too_fast_reason=too_fast_reason, multiplier_ok=multiplier_ok,
               multiplier=peer.get_double("left_wheel_radius_multiplier"),
               zero_ok=zero_ok, zero_reason=zero_reason)
        report("ramps", **_ramps(peer, cmd_vel_out, drive_fast))
    finally:
        report("describe_node_exit", code=node.stop(signal.SIGINT))
    try:
        report("bag", sent_cmd_vel=sent_cmd_vel, **_read_bag(bag, peer))
    finally:
        shutil.rmtree(bag.parent, ignore_errors=True)
    _lifecycle(peer)
    report("describe_bad_values", **_bad_values_at_start(
        "left_wheel_names:=[only_one]", "pose_covariance_diagonal:=[1.0,2.0]", ports=KINEMATIC))


def main() -> None:
    scenario, where = sys.argv[1], Path(sys.argv[2])
    _REPORT.update(path=where, logs=where.parent / f"{where.stem}-serve")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rclpy.init()
    peer = Peer(namespace="/bot" if scenario in ("kill", "describe") else "")
    try:
        {"main": main_scenario, "kill": kill_scenario, "fault": fault_scenario,
         "ddc": ddc_scenario, "imu": imu_scenario,
         "describe": describe_scenario}[scenario](peer)
    finally:
        peer.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    main()
