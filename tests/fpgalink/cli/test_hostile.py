"""The CLI under hostile or careless use (issue 12, CLI part): out-of-range and non-finite
numbers, odd ports, unwritable outputs, full disks, special files, boards that refuse or go
away. Each ends in one line and a documented exit code; nothing reaches the board first."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tests.fpgalink.cli.test_errors import assert_one_line_error
from tests.support.cli import (
    CAN_MOUNT,
    CLI,
    ROOT,
    BoardThread,
    cli_env,
    cli_on_small_disk,
    run_cli,
    start_cli,
)
from tests.support.waiting import wait_until_sync as wait_until

pytestmark = pytest.mark.timeout(90)


@pytest.mark.parametrize(("args", "code", "needles"), [
    (["param", "set", "Kp_Wheel_Pid", "1e39", "-c", "A"], 2, ["Kp_Wheel_PidA", "float32"]),
    (["step", "--to", "1e39", "-c", "A"], 2, ["--to", "float32"]),
    (["step", "--to", "nan", "-c", "A"], 2, ["--to", "finite"]),
    (["step", "--to", "45", "-c", "A", "--hold", "inf"], 2, ["--hold"]),
    (["step", "--to", "45", "-c", "A", "--plot", "/proc/no-such-dir/x.png"], 2,
     ["--plot", "no such directory"]),
    (["step", "--to", "45", "-c", "A", "--plot", "x.txt"], 2, ["--plot", ".png"]),
    (["budget", "--period-ms", "nan"], 2, ["--period-ms", "finite"]),
    (["budget", "--period-ms", "inf"], 2, ["--period-ms"]),
    (["--timeout", "inf", "param", "get", "TsTimerPeriod"], 2, ["--timeout"]),
    (["param", "get", "TsTimerPeriod", "--timeout", "nan"], 2, ["--timeout", "finite"]),
    (["--baud", "99999999999", "param", "get", "TsTimerPeriod"], 2, ["--baud"]),
    (["send", "RV", "--hex", "0000c07f00000000"], 2, ["not finite", "--force"]),
])
def test_bad_numbers_are_one_line_before_anything_is_sent(
    fake_board: Callable[..., BoardThread], args: list[str], code: int, needles: list[str]
) -> None:
    fake = fake_board()
    done = run_cli(*args, env=cli_env(FPGALINK_PORT=fake.url))
    assert done.returncode == code, done.stderr
    assert_one_line_error(done.stderr, *needles)
    assert fake.board.received == []


@pytest.mark.parametrize(("port", "needle"), [
    ("socket://127.0.0.1:99999", "Port out of range"),
    ("loop://", "unsupported port"),
    ("socket://[::1", "socket://"),
])
def test_odd_ports_are_one_line_exit_5(port: str, needle: str) -> None:
    done = run_cli("param", "get", "TsTimerPeriod", "--port", port)
    assert done.returncode == 5, done.stderr
    assert_one_line_error(done.stderr, needle)
    assert "device path, ://" not in done.stderr  # that scheme is not listed as "://"


def test_param_load_with_an_out_of_range_float_is_refused_whole(
    fake_board: Callable[..., BoardThread], tmp_path: Path
) -> None:
    fake = fake_board()
    values = tmp_path / "values.toml"
    values.write_text("TsTimerPeriod = 2\n[A]\nKp_Wheel_Pid = 1e39\n", encoding="utf-8")
    done = run_cli("param", "load", str(values), "--port", fake.url)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, "Kp_Wheel_PidA", "float32")
    assert fake.board.received == []


def test_monitor_to_a_full_device_is_one_line(fake_board: Callable[..., BoardThread]) -> None:
    fake = fake_board()
    with open("/dev/full", "w") as full:
        done = subprocess.run([*CLI, "monitor", "--format", "csv", "--duration", "2",
                               "--port", fake.url], stdout=full, stderr=subprocess.PIPE,
                              text=True, cwd=ROOT, env=cli_env(), timeout=30)
    assert done.returncode == 1, done.stderr
    errors = [li for li in done.stderr.splitlines() if li.startswith("fpgalink-cli: error:")]
    assert len(errors) == 1 and done.stderr.splitlines()[-1] == errors[0], done.stderr
    assert "stdout" in errors[0] and "No space left" in errors[0]
    assert "Traceback" not in done.stderr
    assert fake.board.script.values[(2, 0)] == 0  # telemetry switched back off on the way out


def test_send_reply_shows_a_refusal_and_exits_3(fake_board: Callable[..., BoardThread]) -> None:
    # The documented example: PG of GetDataPeriodical on channel 1, which the board refuses
    # (PN 2, wrong channel; scripted here).
    fake = fake_board(nack=2)
    done = run_cli("send", "PG", "--hex", "0201", "--reply", "PA", "--port", fake.url)
    assert done.returncode == 3, done.stderr
    assert "PN" in done.stdout  # what came back is shown
    assert_one_line_error(done.stderr, "PN")


def test_send_reply_with_a_different_reply_type_still_matches_the_request(
    fake_board: Callable[..., BoardThread]
) -> None:
    fake = fake_board()
    done = run_cli("send", "PG", "--hex", "0200", "--reply", "PA", "--port", fake.url)
    assert done.returncode == 0, done.stderr
    assert "PA" in done.stdout and "param_id=2" in done.stdout


def test_monitor_writes_non_finite_telemetry_as_json_null(
    fake_board: Callable[..., BoardThread]
) -> None:
    fake = fake_board(speed=float("nan"))
    done = run_cli("monitor", "--format", "jsonl", "--duration", "0.5", "--port", fake.url)
    assert done.returncode == 0, done.stderr
    rows = [json.loads(line) for line in done.stdout.splitlines()]  # strict JSON parses
    assert rows and all(r["a_speed"] is None for r in rows)
    assert all(isinstance(r["a_position"], int) for r in rows)
    assert "NaN" not in done.stdout


def test_record_writes_non_finite_telemetry_as_json_null(
    fake_board: Callable[..., BoardThread], tmp_path: Path
) -> None:
    fake = fake_board(speed=float("inf"))
    path = tmp_path / "run.mcap"
    done = run_cli("record", str(path), "--duration", "0.5", "--port", fake.url)
    assert done.returncode == 0, done.stderr
    with path.open("rb") as f:
        rows = [json.loads(m.data) for _, c, m in make_reader(f).iter_messages()
                if c.topic.endswith("/telemetry")]
    assert rows and all(r["a_speed"] is None for r in rows)


@pytest.mark.parametrize("command", ["record", "monitor"])
def test_a_board_lost_mid_run_exits_4_saying_when(
    fake_board: Callable[..., BoardThread], tmp_path: Path, command: str
) -> None:
    fake = fake_board()
    args = [str(tmp_path / "run.mcap")] if command == "record" else ["--format", "jsonl"]
    proc = start_cli(command, *args, "--duration", "4", "--port", fake.url)
    try:
        wait_until(lambda: proc.poll() is not None or any(
            type(e).__name__ == "ParamSet" for e in fake.board.received),
            timeout=15, what="the command to start streaming")
        fake.call(fake.board.vanish())
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 4, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("fpgalink-cli: error: board not answering: 0 since "), err
    assert "s into the run" in last and "Traceback" not in err


# --- outputs that are not plain files -----------------------------------------------------


def test_param_dump_into_a_symlink_keeps_the_link(
    fake_board: Callable[..., BoardThread], tmp_path: Path
) -> None:
    fake = fake_board()
    target = tmp_path / "real.toml"
    target.write_text("old\n")
    link = tmp_path / "link.toml"
    link.symlink_to(target)
    done = run_cli("param", "dump", str(link), "--port", fake.url)
    assert done.returncode == 0, done.stderr
    assert link.is_symlink() and link.resolve() == target
    assert "TsTimerPeriod" in target.read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.toml", "real.toml"]


def test_param_dump_into_a_fifo_streams_and_keeps_the_fifo(
    fake_board: Callable[..., BoardThread], tmp_path: Path
) -> None:
    fake = fake_board()
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got: list[str] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_text()), daemon=True)
    reader.start()
    done = run_cli("param", "dump", str(fifo), "--port", fake.url)
    reader.join(timeout=10)
    assert done.returncode == 0, done.stderr
    assert stat.S_ISFIFO(fifo.stat().st_mode)
    assert got and "TsTimerPeriod" in got[0]


@pytest.mark.skipif(os.geteuid() != 0, reason="making a device node needs root")
def test_param_dump_onto_a_full_device_fails_and_leaves_the_node(
    fake_board: Callable[..., BoardThread], tmp_path: Path
) -> None:
    # A private copy of /dev/full (char 1:7): the real one must not be at risk in a test.
    full = tmp_path / "full"
    os.mknod(full, stat.S_IFCHR | 0o666, os.makedev(1, 7))
    fake = fake_board()
    done = run_cli("param", "dump", str(full), "--port", fake.url)
    assert done.returncode == 1, done.stderr
    assert_one_line_error(done.stderr, str(full), "No space left")
    assert stat.S_ISCHR(full.stat().st_mode)


# --- a full disk during record ----------------------------------------------------------------

@pytest.mark.skipif(not CAN_MOUNT, reason="needs root and unshare for a private tmpfs")
def test_record_mcap_on_a_full_disk_stops_with_a_readable_file(tmp_path: Path) -> None:
    done, path = cli_on_small_disk(tmp_path, "1m", "run.mcap", "record", "{out}", "--port", "emu://",
                                   "--duration", "60", timeout=60)
    assert done.returncode == 1, done.stderr
    assert_one_line_error(done.stderr, "disk is full", "complete up to there")
    said = int(done.stderr.split(" with ")[1].split()[0])
    with path.open("rb") as f:
        reader = make_reader(f)  # the normal reader: summary and footer are there
        assert reader.get_summary() is not None
        messages = list(reader.iter_messages())
    assert len(messages) == said > 1000


@pytest.mark.skipif(not CAN_MOUNT, reason="needs root and unshare for a private tmpfs")
def test_record_csv_on_a_full_disk_ends_at_a_complete_row(tmp_path: Path) -> None:
    done, path = cli_on_small_disk(tmp_path, "1m", "run.csv", "record", "{out}", "--port", "emu://",
                                   "--csv", "--duration", "60", timeout=60)
    assert done.returncode == 1, done.stderr
    assert_one_line_error(done.stderr, "disk is full", "complete rows")
    said = int(done.stderr.split(" with ")[1].split()[0])
    text = path.read_text()
    assert text.endswith("\n")
    lines = text.splitlines()
    width = len(lines[0].split(","))
    assert all(len(line.split(",")) == width for line in lines)
    assert len(lines) - 1 == said > 1000

