"""``drive`` and ``goto`` against the built-in emulated robot: arrival, the distinct exit
codes for a timeout and a supervision stop, plots and recordings, bad descriptions."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tests.fpgalink.cli.test_errors import assert_one_line_error
from tests.support.cli import run_cli

pytestmark = pytest.mark.timeout(90)

PNG = b"\x89PNG\r\n\x1a\n"


def test_goto_arrives_and_plots_odometry_against_truth(tmp_path: Path) -> None:
    plot = tmp_path / "path.png"
    done = run_cli("goto", "0.5", "0.2", "--plot", str(plot), timeout=60)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("arrived at (0.5, 0.2): x 0.4")
    assert lines[1].startswith("odometry: x ") and lines[2].startswith("truth:    x ")
    assert "built-in emulated robot" in done.stderr
    assert plot.read_bytes().startswith(PNG)


def test_goto_out_of_time_exits_6() -> None:
    done = run_cli("goto", "3", "0", "--time-limit", "1.5", timeout=60)
    assert done.returncode == 6, done.stderr
    errors = [li for li in done.stderr.splitlines() if li.startswith("fpgalink-cli: error:")]
    assert len(errors) == 1 and "not at (3, 0) after 1.5 s" in errors[0]


def test_drive_records_odometry_truth_and_commands(tmp_path: Path) -> None:
    record = tmp_path / "drive.mcap"
    done = run_cli("drive", "--v", "0.1", "--omega", "10", "--for", "1", "--record",
                   str(record), timeout=60)
    assert done.returncode == 0, done.stderr
    with record.open("rb") as f:
        topics: dict[str, int] = {}
        for _, channel, _ in make_reader(f).iter_messages():
            topics[channel.topic] = topics.get(channel.topic, 0) + 1
    # 20 Hz for 1 s; fewer when a loaded machine delays the sampling task
    assert topics["/robot/odometry"] > 5 and topics["/robot/truth"] > 5
    assert topics["/robot/command"] > 2
    # What was driven, every sample of both boards (issue 26: these were empty), so plot
    # of the recording shows the wheels turning against their references.
    assert topics["/board/L/telemetry"] > 300 and topics["/board/R/telemetry"] > 300
    with record.open("rb") as f:
        rows = [json.loads(m.data) for _, _, m in
                make_reader(f).iter_messages(topics=["/board/L/telemetry"])]
    reference = max(abs(r["a_ref"]) for r in rows)
    assert reference > 0  # the wheel was driven, and it turned
    assert max(abs(r["a_speed"]) for r in rows if r["a_speed"] is not None) > reference / 2
    png = tmp_path / "drive.png"
    done = run_cli("plot", str(record), "-o", str(png))
    assert done.returncode == 0, done.stderr
    assert png.read_bytes().startswith(PNG)


def test_drive_says_when_a_command_is_scaled_to_the_limits() -> None:
    done = run_cli("drive", "--v", "1.0", "--for", "0.3", timeout=60)
    assert done.returncode == 0, done.stderr
    assert "scaled to 25%" in done.stderr


def test_a_silent_board_stops_drive_with_exit_7() -> None:
    query = "surface=gravel&fault=L:disconnect=1:60"
    done = run_cli("drive", "--v", "0.05", "--for", "8", "--port", f"L=emu://robot/L?{query}",
                   "--port", f"R=emu://robot/R?{query}", timeout=60)
    assert done.returncode == 7, done.stderr
    errors = [li for li in done.stderr.splitlines() if li.startswith("fpgalink-cli: error:")]
    assert len(errors) == 1 and "board L" in errors[0] and "stopped" in errors[0]


@pytest.mark.parametrize(("args", "needle"), [
    (["--surface", "ice"], "no surface 'ice'"),
    (["--port", "L=emu://robot/L"], "no port for R"),
    (["--v", "nan"], "finite"),
])
def test_bad_robot_requests_are_one_line_exit_2(args: list[str], needle: str) -> None:
    done = run_cli("drive", "--for", "0.1", *args)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, needle)


def test_a_bad_robot_file_names_the_key(tmp_path: Path) -> None:
    robot = tmp_path / "robot.toml"
    robot.write_text("wheel_radius = 0\n")
    done = run_cli("goto", "1", "0", "--robot", str(robot))
    assert done.returncode == 2
    assert_one_line_error(done.stderr, str(robot), "wheel_radius")
