"""``fpgalink-ros2 --bag DIR`` on a full or failing disk behaves as ``fpgalink-cli record``
does (issue 37 item 10): the bag closed complete up to there and put in place, one line
saying so, exit 1; a bag that cannot begin leaves nothing; an existing DIR is refused unless
``--force``. Through the node's bag writer (:class:`fpgalink.ros2.bag.NodeBag`) on private
tmpfs mounts, and once through the console script inside tests/ros2/netns.sh."""

from __future__ import annotations

import importlib.util
import os
import shlex
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
NETNS = ROOT / "tests" / "ros2" / "netns.sh"

_missing = next((f"{name} is not installed (the ros2 extra)" for name in ("rclpy", "rosbags")
                 if importlib.util.find_spec(name) is None), None)
pytestmark = [pytest.mark.skipif(_missing is not None, reason=_missing or ""),
              pytest.mark.timeout(240)]

#: Writes JointState messages through the node's bag writer until it stops (or COUNT are
#: in), then closes it; prints what it was told, one line each.
WRITER = textwrap.dedent("""\
    import sys
    from pathlib import Path
    from sensor_msgs.msg import JointState
    from fpgalink.ros2.bag import BagError, NodeBag

    path, count = Path(sys.argv[1]), int(sys.argv[2])
    try:
        bag = NodeBag(path, {"robot": "test"})
    except BagError as exc:
        print(f"open {exc.code}: {exc}")
        sys.exit(0)
    message = JointState(name=["FL", "BL", "FR", "BR"], position=[0.1] * 4,
                         velocity=[0.2] * 4, effort=[0.3] * 4)
    for i in range(count):
        stopped = bag.write("/joint_states", message, 1_000_000 * (i + 1))
        if stopped is not None:
            print(f"stopped after {i}: {stopped}")
            break
    try:
        bag.close()
    except BagError as exc:
        print(f"close {exc.code}: {exc}")
    else:
        print(f"closed: {bag.messages}")
""")


def write_on_small_disk(tmp_path: Path, size: str, count: int
                        ) -> tuple[list[str], list[str], Path]:
    """WRITER into ``bag`` on a tmpfs of ``size``: what it printed, what was left there, and
    a copy of it."""
    small, kept = tmp_path / "small", tmp_path / "kept"
    small.mkdir()
    kept.mkdir()
    script = tmp_path / "writer.py"
    script.write_text(WRITER, encoding="utf-8")
    command = shlex.join([sys.executable, str(script), str(small / "bag"), str(count)])
    shell = (f"mount -t tmpfs -o size={size} tmpfs {small} || exit 97\n{command}\nrc=$?\n"
             f"ls -A {small} > {tmp_path / 'listing'}\ncp -a {small}/. {kept}/\nexit $rc\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)]))
    done = subprocess.run(["unshare", "--mount", "sh", "-c", shell], capture_output=True,
                          text=True, env=env, timeout=180)
    if done.returncode == 97:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    assert done.returncode == 0 and "Traceback" not in done.stderr, done
    return done.stdout.splitlines(), (tmp_path / "listing").read_text().split(), kept


def bag_messages(path: Path) -> int:
    from rosbags.rosbag2 import Reader

    with Reader(path) as reader:
        return sum(1 for _ in reader.messages())


needs_root = pytest.mark.skipif(os.geteuid() != 0 or sys.platform != "linux",
                                reason="a private tmpfs needs root")


@needs_root
def test_a_disk_that_fills_closes_the_bag_complete_and_says_so(tmp_path: Path) -> None:
    said, left, kept = write_on_small_disk(tmp_path, "1200k", 1_000_000)
    stopped, closed = said
    # Was: the bag closed without its reserve, and the node's exit said "N messages".
    assert stopped.startswith("stopped after") and "the disk is full" in stopped
    assert closed.startswith("close 1: --bag ") and "complete up to there" in closed
    assert left == ["bag"]
    assert bag_messages(kept / "bag") == int(closed.split(" with ")[1].split()[0]) > 1000


@needs_root
def test_a_bag_that_cannot_begin_leaves_nothing(tmp_path: Path) -> None:
    said, left, _ = write_on_small_disk(tmp_path, "300k", 10)
    assert len(said) == 1 and said[0].startswith("open 1: --bag ")
    assert "the disk is full" in said[0] and "no bag left" in said[0]
    assert left == []  # was: a bag directory holding a stub


def test_an_existing_bag_is_refused_unless_force(tmp_path: Path) -> None:
    from fpgalink.ros2.bag import BagError, NodeBag

    target = tmp_path / "bag"
    target.mkdir()
    (target / "mine").write_text("keep me")
    with pytest.raises(BagError) as refused:
        NodeBag(target, {})
    assert refused.value.code == 2 and "exists; --force replaces it" in str(refused.value)
    bag = NodeBag(target, {}, force=True)
    bag.close()
    assert (target / "metadata.yaml").is_file() and not (target / "mine").exists()


def test_the_node_with_bag_on_a_full_disk_exits_1_with_one_line(tmp_path: Path) -> None:
    if os.geteuid() != 0:
        pytest.skip("a private tmpfs needs root")
    probe = subprocess.run([str(NETNS), "true"], capture_output=True, text=True, check=False)
    if probe.returncode != 0:
        pytest.skip(f"no network namespace: {probe.stderr.strip()}")
    small, log = tmp_path / "small", tmp_path / "node.log"
    small.mkdir()
    node = shlex.join([sys.executable, "-m", "fpgalink.ros2", "--bag", str(small / "bag")])
    # The node on the emulated robot publishes on its own; once its bag has stopped (the
    # line it logs), it is stopped as a user would, and its exit and last words kept.
    shell = textwrap.dedent(f"""\
        mount -t tmpfs -o size=1200k tmpfs {small} || exit 97
        {node} > {log} 2>&1 &
        pid=$!
        tries=0
        until grep -q "recording stopped" {log} || [ $tries -ge 1200 ]; do
            sleep 0.1; tries=$((tries + 1))
        done
        kill -INT $pid
        wait $pid
        rc=$?
        ls -A {small} > {tmp_path / 'listing'}
        cp -a {small}/. {tmp_path}/kept/
        exit $rc
        """)
    (tmp_path / "kept").mkdir()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)]),
               ROS_LOG_DIR=str(tmp_path / "ros-log"), RCUTILS_COLORIZED_OUTPUT="0")
    done = subprocess.run([str(NETNS), "sh", "-c", shell], capture_output=True, text=True,
                          env=env, timeout=200, check=False)
    if done.returncode == 97:
        pytest.skip("cannot mount a tmpfs here")
    said = log.read_text()
    assert done.returncode == 1, said
    errors = [line for line in said.splitlines() if line.startswith("fpgalink-ros2: error:")]
    assert len(errors) == 1, said
    assert "the disk is full" in errors[0] and "complete up to there" in errors[0], said
    assert "Traceback" not in said
    assert (tmp_path / "listing").read_text().split() == ["bag"]
    assert bag_messages(tmp_path / "kept" / "bag") == int(
        errors[0].split(" with ")[1].split()[0]) > 100
