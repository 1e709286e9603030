"""``--rosbag2 DIR`` (record, drive, goto): a rosbag2 with MCAP storage, CDR messages and
``ros2msg`` schemas, read back with rclpy's own deserialiser (the one ``ros2 bag play``
uses) and checked against what the robot did; bad paths and a full disk get one clear line.

Reading needs the ros2 extra (rclpy): without it these tests skip, unless
``FPGALINK_REQUIRE_ROS2=1`` (``make test``). Nothing here starts a DDS participant."""

from __future__ import annotations

import collections
import importlib.util
import itertools
import json
import math
import os
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from fpgalink.boardclock import MAX_SLEW
from tests.fpgalink.cli.test_errors import assert_one_line_error
from tests.support.cli import (
    CAN_MOUNT,
    ROOT,
    cli_env,
    cli_on_small_disk,
    run_cli,
)

_missing = next((f"{name} is not installed (the ros2 extra)" for name in ("rclpy", "rosbags")
                 if importlib.util.find_spec(name) is None), None)
if _missing is not None and os.environ.get("FPGALINK_REQUIRE_ROS2") == "1":
    raise RuntimeError(f"the rosbag2 tests must run here: {_missing}")
pytestmark = pytest.mark.skipif(_missing is not None, reason=_missing or "")

TYPES = {"/joint_states": ("sensor_msgs.msg", "JointState"),
         "/odom": ("nav_msgs.msg", "Odometry"),
         "/truth": ("nav_msgs.msg", "Odometry"),
         "/diagnostics": ("diagnostic_msgs.msg", "DiagnosticArray")}


def read_bag(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """Topic → [(bag time ns, message)], deserialised by rclpy."""
    import importlib

    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader

    out: dict[str, list[tuple[int, Any]]] = {}
    with Reader(path) as reader:
        for connection, timestamp, data in reader.messages():
            module, name = TYPES[connection.topic]
            kind = getattr(importlib.import_module(module), name)
            out.setdefault(connection.topic, []).append(
                (timestamp, deserialize_message(bytes(data), kind)))
    return out


def stamp_ns(message: Any) -> int:
    return int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)


@pytest.fixture(scope="module")
def driven(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    bag = tmp_path_factory.mktemp("bags") / "drive"
    # On the ideal surface the emulated robot's body is the kinematic one, which odometry
    # describes exactly: the checks below compare odom with the truth to the centimetre.
    done = run_cli("drive", "--v", "0.2", "--omega", "10", "--for", "2", "--surface",
                       "ideal", "--rosbag2", str(bag), timeout=60)
    assert done.returncode == 0, done.stderr
    return bag, done.stdout + done.stderr


def test_the_bag_is_mcap_with_cdr_messages_and_ros2msg_schemas(driven: tuple[Path, str]
                                                               ) -> None:
    bag, _ = driven
    assert (bag / "metadata.yaml").is_file()
    with (bag / "drive.mcap").open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        assert {c.topic for c in summary.channels.values()} == set(TYPES)
    assert "/truth" in (bag / "metadata.yaml").read_text()


def test_joint_states_are_every_set_of_samples_on_the_boards_clock(
        driven: tuple[Path, str]) -> None:
    topics = read_bag(driven[0])
    joints = [m for _, m in topics["/joint_states"]]
    # 1 kHz telemetry for 2 s: a set per pair of fresh samples, so as many as the host's
    # reads (a loaded host reads in bursts, a set per burst): some, whatever the load.
    assert len(joints) > 20
    assert all(list(m.name) == ["FL", "BL", "FR", "BR"] for m in joints)
    stamps = [stamp_ns(m) for m in joints]
    gaps = [b - a for a, b in itertools.pairwise(stamps)]
    # Board time: every gap is a whole number k of the boards' 1 ms ticks, never 0, less
    # what the clock's offset slews down by (at most 5 % of it: a first sample's delay, or
    # the in-process emulator's catch-up burst at start, worked off) and plus what a drift
    # correction adds (microseconds).
    def whole_ticks(gap: int) -> bool:
        k = max(1, math.ceil((gap - 50_000) / 1_000_000))
        return (1 - MAX_SLEW) * k * 1_000_000 - 1 <= gap

    assert all(g > 0 and whole_ticks(g) for g in gaps), [
        (i, g) for i, g in enumerate(gaps) if not (g > 0 and whole_ticks(g))][:5]
    # Most of them exactly so: the offset moves only while a smaller delay is found.
    exact = sum(g % 1_000_000 == 0 for g in gaps)
    assert exact > len(gaps) // 2, collections.Counter(gaps).most_common(5)
    # Driving forward and turning left: the right wheels faster, all forward.
    steady = joints[len(joints) // 2:]
    assert all(min(m.velocity) > 0 for m in steady)
    assert statistics.median(m.velocity[2] - m.velocity[0] for m in steady) > 0


def test_odom_follows_the_wheels_and_the_truth(driven: tuple[Path, str]) -> None:
    topics = read_bag(driven[0])
    odom = [m for _, m in topics["/odom"]]
    truth = [m for _, m in topics["/truth"]]
    assert odom[0].header.frame_id == "odom" and odom[0].child_frame_id == "base_link"
    end, true_end = odom[-1].pose.pose.position, truth[-1].pose.pose.position
    assert math.hypot(end.x, end.y) > 0.2
    # The last truth is at most 10 ms older than the last odometry: 0.2 m/s × 10 ms.
    assert math.hypot(end.x - true_end.x, end.y - true_end.y) < 0.01
    # Body speed = wheel radius × the mean wheel speed (seed eq. 2.18), sample by sample.
    joints = [m for _, m in topics["/joint_states"]]
    pairs = list(zip(joints[len(joints) // 2:], odom[len(odom) // 2:], strict=False))
    error = statistics.median(abs(0.2 * statistics.fmean(j.velocity) - o.twist.twist.linear.x)
                              for j, o in pairs)
    assert error < 0.002
    covariance = list(odom[-1].pose.covariance)
    assert covariance[0] > 0 and covariance[14] == 1e6  # x estimated, z not


def test_truth_is_recorded_at_most_every_10_ms(driven: tuple[Path, str]) -> None:
    """One clock for both boards' sample streams: /truth at 100 Hz at most, not once per
    board (which doubled it)."""
    times = [t for t, _ in read_bag(driven[0])["/truth"]]
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert len(gaps) > 50
    assert min(gaps) >= 10_000_000 - 1  # ns; host receive times, rounded to whole ns


def test_diagnostics_once_a_second_per_board_and_supervision(driven: tuple[Path, str]
                                                             ) -> None:
    topics = read_bag(driven[0])
    arrays = [m for _, m in topics["/diagnostics"]]
    assert len(arrays) >= 1
    names = [s.name for s in arrays[-1].status]
    assert names == ["fpgalink: board L", "fpgalink: board R", "fpgalink: supervision"]
    levels = [s.level[0] if isinstance(s.level, bytes) else s.level for s in arrays[-1].status]
    assert levels == [0, 0, 0]


def test_record_rosbag2_records_the_robot_at_rest(tmp_path: Path) -> None:
    bag = tmp_path / "rest"
    done = run_cli("record", "--rosbag2", str(bag), "--duration", "1", timeout=60)
    assert done.returncode == 0, done.stderr
    said = int(done.stderr.split("recorded ")[1].split()[0])
    topics = read_bag(bag)
    assert sum(len(v) for v in topics.values()) == said
    assert all(v == 0.0 for _, m in topics["/joint_states"] for v in m.velocity)


@pytest.mark.parametrize(("args", "needle"), [
    (["record", "x.mcap", "--rosbag2", "{bag}"], "no FILE, --csv or --passive"),
    (["record", "--rosbag2", "{bag}", "--csv"], "no FILE, --csv or --passive"),
    (["record"], "give FILE"),
    (["record", "x.mcap", "--surface", "gravel"], "go with --rosbag2"),
    (["record", "--rosbag2", "{exists}"], "exists; --force replaces it"),
    (["drive", "--for", "1", "--rosbag2", "{nodir}"], "no such directory"),
])
def test_bad_bag_arguments_are_one_line_exit_2(tmp_path: Path, args: list[str],
                                               needle: str) -> None:
    (tmp_path / "exists").mkdir()
    paths = {"bag": str(tmp_path / "bag"), "exists": str(tmp_path / "exists"),
             "nodir": str(tmp_path / "no" / "such" / "bag")}
    done = run_cli(*(a.format(**paths) for a in args), cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, needle)


def test_without_rosbags_the_option_says_how_to_install(tmp_path: Path) -> None:
    code = ("import sys\nsys.modules['rosbags'] = None\n"
            "from fpgalink.cli import main\nmain()")
    done = subprocess.run([sys.executable, "-c", code, "record", "--rosbag2",
                           str(tmp_path / "bag"), "--duration", "1"], capture_output=True,
                          text=True, cwd=ROOT, env=cli_env(), timeout=60)
    assert done.returncode == 8, done.stderr  # not installed
    assert "pip install 'fpgalink[ros2]'" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "bag").exists()


@pytest.mark.skipif(not CAN_MOUNT, reason="needs root and unshare for a private tmpfs")
def test_a_full_disk_stops_the_bag_complete_up_to_there(tmp_path: Path) -> None:
    done, bag = cli_on_small_disk(tmp_path, "2m", "bag", "drive", "--v", "0.1", "--for", "60",
                                  "--rosbag2", "{out}")
    assert done.returncode == 1, done.stderr
    errors = [line for line in done.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and "the disk is full" in errors[0], done.stderr
    said = int(errors[0].split(" with ")[1].split()[0])
    topics = read_bag(bag)
    assert sum(len(v) for v in topics.values()) == said > 1000
    assert not (bag / ".fpgalink-reserve").exists()


def test_plot_reads_the_bag_the_cli_wrote(driven: tuple[Path, str], tmp_path: Path) -> None:
    # issue 26: plot of a --rosbag2 directory (CDR through rosbags): each wheel's velocity
    # and the body's twist by default, and a field that is not there named with what is.
    bag, _ = driven
    png = tmp_path / "bag.png"
    done = run_cli("plot", str(bag), "-o", str(png), timeout=60)
    assert done.returncode == 0, done.stderr
    assert png.read_bytes().startswith(b"\x89PNG")
    assert "from 2 topic(s)" in done.stderr
    done = run_cli("plot", str(bag), "--topic", "/odom", "--fields", "twist.nosuch",
                   "-o", str(png), "--force", timeout=60)
    assert done.returncode == 2
    assert_one_line_error(done.stderr, "no field twist.nosuch", "twist.twist.linear.x",
                          "/joint_states")


def test_record_and_rosbag2_together_write_both(tmp_path: Path) -> None:
    # The bag's tasks used to replace --record's telemetry tasks: both run side by side.
    bag, record = tmp_path / "bag", tmp_path / "run.mcap"
    done = run_cli("drive", "--v", "0.1", "--for", "1", "--record", str(record),
                   "--rosbag2", str(bag), timeout=60)
    assert done.returncode == 0, done.stderr
    # How much of the boards' time a second of this machine's holds depends on its load
    # (the in-process boards keep the link's time): what holds is that the record has every
    # sample of each board from its first to its last (nothing lost at the end either), and
    # the bag its joint states beside them.
    with record.open("rb") as f:
        counters = collections.defaultdict(list)
        for _, channel, message in make_reader(f).iter_messages():
            if channel.topic.endswith("/telemetry"):
                counters[channel.topic].append(json.loads(message.data)["counter"])
    assert set(counters) == {"/board/L/telemetry", "/board/R/telemetry"}
    for got in counters.values():
        assert len(got) > 50 and got == list(range(got[0], got[0] + len(got))), got[-3:]
    assert len(read_bag(bag)["/joint_states"]) > 10
