"""The ROS-less route to Foxglove: ``fpgalink-ros2 --foxglove PORT`` (or ``-p
foxglove:=PORT``) serves the live view beside its ROS topics (inside a loopback-only
network namespace, as every DDS participant in the suite runs; the client speaks
Foxglove's protocol from the same namespace)."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys

import pytest

from tests.support.cli import ROOT
from tests.support.scripts import BIN

NETNS = ROOT / "tests" / "ros2" / "netns.sh"

INSIDE = """
import asyncio, json, re, select, shutil, subprocess, sys, time
from tests.support.foxglove import watch
node = subprocess.Popen([sys.argv[1], *json.loads(sys.argv[2])], stderr=subprocess.PIPE,
                        text=True)
# A ROS 2 node starts slowly on a loaded machine (rclpy, DDS, the robot): beside two busy
# loops one did not say where its live view was within 60 s. Waited for longer, and what it
# said meanwhile is passed on, so a node that never says is seen.
url, deadline, started = None, time.monotonic() + 120, time.monotonic()
while url is None and time.monotonic() < deadline:
    if select.select([node.stderr], [], [], 0.5)[0]:
        line = node.stderr.readline()
        if not line:
            break  # the node ended
        sys.stderr.write(line)
        found = re.search(r"live view for Foxglove on (ws://\\S+)", line)
        url = found.group(1) if found else url
if url is None:
    print(f"no live view line after {time.monotonic() - started:.0f} s; the node "
          f"{'ended: ' + str(node.poll()) if node.poll() is not None else 'still runs'}",
          file=sys.stderr)
    if node.poll() is None and shutil.which("gdb"):
        # Where each thread waits (twice beside two busy loops a node said "up" and then
        # nothing, never reproduced alone): the frames only, as the last thing said.
        dump = subprocess.run(["gdb", "-p", str(node.pid), "-batch", "-ex",
                               "thread apply all bt 25"], capture_output=True, text=True,
                              timeout=45, check=False).stdout
        print("\\n".join(line[:160] for line in dump.splitlines()
                        if line.startswith(("#", "Thread"))), file=sys.stderr)
got = asyncio.run(watch(url, 4.0)) if url else None
node.terminate()
try:
    node.communicate(timeout=30)
except subprocess.TimeoutExpired:  # a node that does not end on SIGTERM: said by its code
    node.kill()
    node.communicate()
print(json.dumps(None if got is None else {
    "topics": sorted(got.topics()),
    "counts": {t: len(m) for t, m in got.messages.items()},
    "returncode": node.returncode}))
"""


@pytest.mark.timeout(240)
@pytest.mark.parametrize("route", [["--foxglove", "0"], ["--ros-args", "-p", "foxglove:=0"]],
                         ids=["option", "node-parameter"])
def test_the_node_serves_the_live_view_without_ros(route: list[str]) -> None:
    """Asked on the command line, or as the node's ``foxglove`` parameter (a launch file's
    way)."""
    if importlib.util.find_spec("rclpy") is None:
        pytest.skip("rclpy is not installed")
    probe = subprocess.run([str(NETNS), "true"], capture_output=True, text=True, check=False)
    if probe.returncode != 0:
        pytest.skip(f"no network namespace: {probe.stderr.strip()}")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)]),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    done = subprocess.run([str(NETNS), sys.executable, "-c", INSIDE,
                           str(BIN / "fpgalink-ros2"), json.dumps(route)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=220, check=False)
    assert done.returncode == 0, done.stderr[-30000:]
    facts = json.loads(done.stdout.strip().splitlines()[-1])
    assert facts is not None, done.stderr[-30000:]
    assert {"/board/L/telemetry", "/robot/pose", "/tf", "/robot_description"} <= set(
        facts["topics"])
    assert facts["counts"]["/board/L/telemetry"] > 100
    assert facts["counts"]["/robot/pose"] > 10
    assert facts["returncode"] == 0  # SIGTERM: a clean stop
