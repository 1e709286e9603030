"""The ROS 2 node with two boards at 1 kHz telemetry: host CPU and the latency from each
board's sample to ``joint_states`` delivery in a separate rclpy peer, publishing at 100 Hz
and at the full 1 kHz.

``fpgaemu serve --robot --pty`` serves the boards (its own process), ``fpgalink-ros2`` talks
to them over the ptys (its own process), and this script is the peer: it holds the enable and
a ``cmd_vel`` (so the wheels turn and their speeds identify each sample), subscribes to
``joint_states`` with the sensor-data QoS, and reads the emulator's truth endpoint.

Latency: the emulator's truth lines give each board tick's (board time, wheel speeds) and the
host time the boards were advanced to, which maps board time onto the host clock; a
``joint_states`` stamp is the node's mapping of the same board time (one fixed offset, found
by matching speeds). Latency = the peer's receive time − the sample's host time: it includes
the TM's time on the wire (about 0.5 ms at 1 MBd), the node, DDS and the peer's executor.
CPU: each process's user + system time over the measured window, in % of one core.

Everything runs inside a private network namespace with loopback only
(tests/ros2/netns.sh); the script re-executes itself there. ``--quick``: 3 s per rate.
"""

from __future__ import annotations

import json
import math
import os
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from benchmarks._common import (
    common_parser,
    environment_line,
    percentile,
    print_table,
    report_header,
    write_results,
)
from tests.support.serving import start_serve

NAME = "ros2"
ROOT = Path(__file__).resolve().parents[1]
NETNS = ROOT / "tests" / "ros2" / "netns.sh"
RATES_HZ = (100.0, 1000.0)
DEFAULT_SECONDS, QUICK_SECONDS = 15.0, 3.0
WARM_UP_S = 2.0
READY_TIMEOUT_S = 60.0
CLK_TCK = os.sysconf("SC_CLK_TCK")


def float32(value: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", value))[0])


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (/proc/PID/stat fields 14 and 15)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


class TruthReader:
    def __init__(self, url: str) -> None:
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        self._sock = socket.create_connection((host, int(port)), timeout=READY_TIMEOUT_S)
        self.lines: list[dict[str, Any]] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self._sock.makefile("r"):
            self.lines.append(json.loads(line))

    def close(self) -> None:
        self._sock.close()


def start(*args: str) -> tuple[subprocess.Popen[str], list[list[str]]]:
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True)
    return proc, []


def stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def measure_rate(rate: float, seconds: float) -> dict[str, Any]:
    import rclpy
    from geometry_msgs.msg import Twist
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Bool

    serve = start_serve("--robot", "--pty", "--surface", "gravel")
    ports = dict(serve.ready)
    assert serve.truth is not None
    truth = TruthReader(serve.truth)
    node, _ = start(sys.executable, "-m", "fpgalink.ros2",
                    *(f"--port={b}={u}" for b, u in ports.items()),
                    "--ros-args", "-p", f"joint_state_rate:={rate}",
                    "--log-level", "warn")
    peer = Node("benchmark_peer")
    received: list[tuple[int, int, tuple[float, ...]]] = []  # stamp, receive, identity
    measuring = [False]

    def on_joints(message: Any) -> None:
        if measuring[0]:
            stamp = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
            received.append((stamp, time.time_ns(),  # board L's wheels define the stamp
                             (*message.velocity[:2], *message.position[:2])))

    peer.create_subscription(JointState, "joint_states", on_joints, qos_profile_sensor_data)
    enable = peer.create_publisher(Bool, "enable", 10)
    command = peer.create_publisher(Twist, "cmd_vel", 10)
    twist = Twist()
    # Fast enough that each wheel's count changes nearly every 1 ms tick (identifies ticks).
    twist.linear.x, twist.angular.z = 0.2, math.radians(5)
    last_hold = 0.0

    def spin_for(duration: float) -> None:
        nonlocal last_hold
        end = time.monotonic() + duration
        while time.monotonic() < end:
            if time.monotonic() - last_hold > 0.1:
                last_hold = time.monotonic()
                enable.publish(Bool(data=True))
                command.publish(twist)
            rclpy.spin_once(peer, timeout_sec=0.005)

    try:
        deadline = time.monotonic() + READY_TIMEOUT_S
        while peer.count_publishers("joint_states") == 0 or not truth.lines:
            if time.monotonic() > deadline or node.poll() is not None:
                raise RuntimeError("the node did not come up")
            spin_for(0.1)
        spin_for(WARM_UP_S)
        first_line = len(truth.lines)
        measuring[0] = True
        cpu_before = {"node": cpu_seconds(node.pid), "serve": cpu_seconds(serve.pid)}
        peer_before = time.process_time()
        started = time.monotonic()
        spin_for(seconds)
        window = time.monotonic() - started
        measuring[0] = False
        cpu = {n: (cpu_seconds(pid) - cpu_before[n]) / window * 100
               for n, pid in (("node", node.pid), ("serve", serve.pid))}
        cpu["peer"] = (time.process_time() - peer_before) / window * 100
        lines = truth.lines[first_line:]
    finally:
        peer.destroy_node()
        stop(node)
        serve.discard()
        truth.close()
    return {"rate_hz": rate, "window_s": window, "messages": len(received),
            "cpu_percent": cpu, **latencies(received, lines)}


def _identity(line: dict[str, Any], turn_counts: int) -> tuple[float, ...]:
    """What a JointState stamped with this tick carries for board L's wheels (FL, BL): speed
    and position (the seed robot: forward-positive, IncSenzRes 500). Board R's sample in the
    same message is its latest, which may be a tick older."""
    board = line["boards"]["L"]
    speeds = [math.radians(float32(board[f"speed_{c}"])) for c in "ab"]
    positions = [math.tau * board[f"position_{c}"] / turn_counts for c in "ab"]
    return (*speeds, *positions)


def latencies(received: list[tuple[int, int, tuple[float, ...]]],
              lines: list[dict[str, Any]]) -> dict[str, Any]:
    """Board sample → delivery. A message whose board-L speeds and encoder positions equal
    a truth line's is that tick's sample; its stamp minus the tick's board time is the
    node's fixed offset (the most frequent one, should two ticks look alike)."""
    turn_counts = 10 * 500
    stamps: dict[tuple[float, ...], list[int]] = {}
    for stamp, _, identity in received:
        stamps.setdefault(identity, []).append(stamp)
    candidates: set[int] = set()
    for line in lines:
        for stamp in stamps.get(_identity(line, turn_counts), []):
            candidates.add(stamp - line["boards"]["L"]["t_us"] * 1000)
    if not candidates or not lines:
        return {"matched": 0, "latency_ms": None}
    # Two ticks can look alike (no encoder edge between them); a wrong offset then also
    # pairs messages with ticks that differ. The offset: every pairing agrees, most pairs.
    by_stamp = {stamp: identity for stamp, _, identity in received}

    def score(offset: int) -> tuple[int, int]:
        agree = differ = 0
        for line in lines:
            identity = by_stamp.get(offset + line["boards"]["L"]["t_us"] * 1000)
            if identity is not None:
                if identity == _identity(line, turn_counts):
                    agree += 1
                else:
                    differ += 1
        return -differ, agree

    offset = max(candidates, key=score)
    differ, agree = score(offset)
    # Host epoch of board time 0: the truth lines are written once the boards caught up with
    # host_time; a line written late only makes the estimate later, so take the earliest.
    origin_ns = min(round(line["host_time"] * 1e9) - round(line["boards"]["L"]["now_s"] * 1e9)
                    for line in lines)
    delays = [(receive - (origin_ns + stamp - offset)) / 1e6 for stamp, receive, _ in received]
    return {"matched": agree, "mismatched": -differ, "candidates": len(candidates),
            "latency_ms": {"p50": percentile(delays, 50), "p99": percentile(delays, 99),
                           "max": max(delays), "mean": statistics.fmean(delays)}}


def run(seconds: float) -> list[dict[str, Any]]:
    import rclpy

    rclpy.init()
    try:
        return [measure_rate(rate, seconds) for rate in RATES_HZ]
    finally:
        rclpy.shutdown()


def main() -> None:
    parser = common_parser(__doc__, NAME, f"{QUICK_SECONDS:g} s per rate")
    parser.add_argument("--seconds", type=float, default=None,
                        help=f"measured window per rate (default {DEFAULT_SECONDS:g})")
    args = parser.parse_args()
    if os.environ.get("FPGALINK_IN_NETNS") != "1":  # loopback only, or not at all
        env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                   PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT),
                                                            os.environ.get("PYTHONPATH")])))
        with tempfile.TemporaryDirectory(prefix="fpgalink-ros-logs-") as logs:
            env.setdefault("ROS_LOG_DIR", logs)  # rcl's log files, gone with the run
            done = subprocess.run([str(NETNS), sys.executable, "-m", "benchmarks.ros2",
                                   *sys.argv[1:]], cwd=ROOT, env=env, check=False)
        sys.exit(done.returncode)
    seconds = args.seconds or (QUICK_SECONDS if args.quick else DEFAULT_SECONDS)
    report = report_header(NAME, ["ros-jazzy-rclpy", "rosbags"])
    results = run(seconds)
    report["config"] = {"quick": args.quick, "seconds": seconds, "rates_hz": list(RATES_HZ),
                        "boards": 2, "telemetry_hz": 1000, "baud": 1_000_000}
    report["results"] = results
    print(environment_line(report))
    rows = []
    for result in results:
        latency = result["latency_ms"]
        cpu = result["cpu_percent"]
        rows.append([f"{result['rate_hz']:g} Hz", f"{result['messages'] / result['window_s']:.0f}",
                     f"{cpu['node']:.1f}", f"{cpu['serve']:.1f}", f"{cpu['peer']:.1f}",
                     "-" if latency is None else f"{latency['p50']:.2f}",
                     "-" if latency is None else f"{latency['p99']:.2f}",
                     str(result["matched"])])
    print_table(["joint_state_rate", "msgs/s", "node CPU %", "serve CPU %", "peer CPU %",
                 "latency p50 ms", "p99 ms", "samples matched"], rows)
    path = write_results(NAME, report, args.output)
    print(f"results: {path}")


if __name__ == "__main__":
    main()
