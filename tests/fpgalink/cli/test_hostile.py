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
    done = run_cli("param", "dump", str(link), "--force", "--port", fake.url)
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



# --- round 2 (issue 24): robot files, TOML everywhere, foreign endpoints, recordings --------

#: 20,000 nested arrays in 40 KB: tomllib recursed until the interpreter's stack ran out.
DEEP_TOML = "x = " + "[" * 20_000 + "]" * 20_000 + "\n"


def _robot(tmp_path: Path, replace: str, by: str, name: str = "robot.toml") -> Path:
    from fpgalink.protocol.robot import SEED_ROBOT_TOML

    assert replace in SEED_ROBOT_TOML, replace
    path = tmp_path / name
    path.write_text(SEED_ROBOT_TOML.replace(replace, by), encoding="utf-8")
    return path


#: (what the file says instead of the seed's, what the one line names)
BAD_ROBOTS = [
    pytest.param('surface = "gravel"', 'surface = ["gravel"]', "surface", id="surface-list"),
    pytest.param('surface = "gravel"', "surface = {a = 1}", "surface", id="surface-table"),
    pytest.param('channel = "A"', 'channel = ["A"]', "channel", id="channel-list"),
    pytest.param('channel = "A"', "channel = {x = 1}", "channel", id="channel-table"),
    pytest.param('board = "L"', 'board = "L=x y"', "board name", id="board-name"),
    pytest.param("y = 0.33", "y = 5e-324", "wheels.FL.y", id="wheel-on-centre-line"),
    pytest.param("y = 0.33", "y = 1e-300", "wheels.FL.y", id="wheel-at-1e-300"),
    pytest.param("wheel_radius = 0.20", "wheel_radius = 1e-300", "wheel_radius",
                 id="tiny-wheel"),
    pytest.param("max_linear_speed = 0.25", "max_linear_speed = 1e-300", "max_linear_speed",
                 id="tiny-speed-limit"),
    pytest.param("x = -0.29\ny = 0.33", "x = 0.28\ny = 0.33", "overlap", id="wheels-overlap"),
]


@pytest.mark.parametrize(("replace", "by", "needle"), BAD_ROBOTS)
def test_a_bad_robot_file_is_one_line_exit_2_for_the_cli(
        tmp_path: Path, replace: str, by: str, needle: str) -> None:
    # Unhashable values gave a TypeError traceback; a degenerate track a robot that drove on
    # with its odometry task dead.
    robot = _robot(tmp_path, replace, by)
    done = run_cli("drive", "--for", "0.1", "--robot", str(robot))
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, str(robot), needle)


def _bad_inputs(tmp_path: Path) -> dict[str, Path]:
    deep = tmp_path / "deep.toml"
    deep.write_text(DEEP_TOML, encoding="ascii")
    return {"deep": deep, "zero": Path("/dev/zero")}


@pytest.mark.parametrize("kind", ["deep", "zero"])
@pytest.mark.parametrize("how", ["robot", "config", "config-robot", "param-load",
                                 "param-load-stdin"])
def test_every_toml_the_cli_reads_is_bounded_and_one_line(
        tmp_path: Path, kind: str, how: str) -> None:
    # A deep file: RecursionError traceback. /dev/zero: read until memory ran out.
    bad = _bad_inputs(tmp_path)[kind]
    if how == "param-load-stdin" and kind == "zero":
        done = run_cli("param", "load", "-", "--port", "emu://", input="\0" * (2 << 20))
        needle = "stdin"
    elif how == "param-load-stdin":
        done = run_cli("param", "load", "-", "--port", "emu://", input=DEEP_TOML)
        needle = "stdin"
    else:
        if how == "config-robot":
            config = tmp_path / "fpgalink.toml"
            config.write_text(f'robot = "{bad}"\n', encoding="utf-8")
            args = ["--config", str(config), "drive", "--for", "0.1"]
        else:
            args = {"robot": ["drive", "--for", "0.1", "--robot", str(bad)],
                    "config": ["--config", str(bad), "config"],
                    "param-load": ["param", "load", str(bad), "--port", "emu://"]}[how]
        done = run_cli(*args)
        needle = str(bad)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, needle,
                          "nested too deeply" if kind == "deep" else "larger than 1 MiB")


@pytest.mark.parametrize(("config", "env", "needle"), [
    ('[ports]\n"R=x" = "emu://"\n', {}, "[ports] key 'R=x'"),
    ('[ports]\nL = "emu://"\nR = "  "\n', {}, "empty port"),
    ('board = "L x"\n', {}, "board 'L x'"),
    ("", {"FPGALINK_PORT": "   "}, "FPGALINK_PORT is blank"),
    ("", {"FPGALINK_CONFIG": "  "}, "FPGALINK_CONFIG is blank"),
])
def test_config_names_and_blanks_are_refused(tmp_path: Path, config: str,
                                             env: dict[str, str], needle: str) -> None:
    # A [ports] key was parsed again as NAME=URL ("R=x" became board R at "x=emu://"); a
    # blank FPGALINK_PORT gave "0 are configured (, from …)".
    path = tmp_path / "fpgalink.toml"
    path.write_text(config, encoding="utf-8")
    done = run_cli("config", cwd=tmp_path, env=cli_env(**env))
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, needle)


def test_an_empty_config_name_is_an_error_not_no_config(tmp_path: Path) -> None:
    (tmp_path / "fpgalink.toml").write_text('port = "emu://?seed=3"\n', encoding="utf-8")
    for args in (["--config", "", "config"], ["config", "--config", ""]):
        done = run_cli(*args, cwd=tmp_path)
        assert done.returncode == 2, done.stderr
        assert_one_line_error(done.stderr, "--config", "empty file name")


# --- a truth endpoint that is not one -----------------------------------------------------------

GOOD_POSE = b'{"t": 0.5, "x": 0.25, "y": -0.5, "theta": 0.1, "v": 0.0, "omega": 0.0}\n'
#: What a foreign endpoint might send instead of a pose, each one line.
NOT_POSES = [
    b'{"a": 1}\n',
    b'{"x": "1", "y": 0, "theta": 0, "v": 0, "omega": 0}\n',
    b'{"x": null, "y": 0, "theta": 0, "v": 0, "omega": 0}\n',
    b'{"x": true, "y": 0, "theta": 0, "v": 0, "omega": 0}\n',
    b'{"x": 1' + b"0" * 400 + b', "y": 0, "theta": 0, "v": 0, "omega": 0}\n',
    b"[1, 2, 3]\n",
    b"[" * 100_000 + b"]" * 100_000 + b"\n",
    b"not json at all\n",
    b'{"x": ' + b"1" * 200_000 + b"}\n",
]


class FakeTruth:
    """A TCP endpoint in a thread that sends ``lines`` then, if ``then_good``, a good pose
    every 20 ms until the reader goes."""

    def __init__(self, lines: list[bytes], then_good: bool) -> None:
        import socket

        self.lines, self.then_good = lines, then_good
        self.server = socket.create_server(("127.0.0.1", 0))
        self.url = f"socket://127.0.0.1:{self.server.getsockname()[1]}"
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        import time

        connection, _ = self.server.accept()
        with connection:
            try:
                for line in self.lines:
                    connection.sendall(line)
                while self.then_good:
                    connection.sendall(GOOD_POSE)
                    time.sleep(0.02)
            except OSError:
                return

    def close(self) -> None:
        self.server.close()


@pytest.mark.parametrize("then_good", [True, False], ids=["then-poses", "never-a-pose"])
def test_a_truth_endpoint_sending_what_is_not_a_pose_is_skipped_and_counted(
        then_good: bool) -> None:
    # JSON without numeric x/y/theta: KeyError/TypeError traceback, exit 1.
    truth = FakeTruth(NOT_POSES, then_good)
    try:
        done = run_cli("drive", "--for", "0.6", "--truth", truth.url)
    finally:
        truth.close()
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    assert f"skipped {len(NOT_POSES)} line(s) that were not a pose" in done.stderr
    if then_good:  # the pose at the start is odometry's zero (the body stood still there)
        assert "truth:    x 0.000 m, y 0.000 m" in done.stdout
    else:
        assert "no pose received" in done.stderr and "truth:" not in done.stdout


# --- a recording with a bad message -------------------------------------------------------------


def test_plot_skips_and_counts_a_bad_message_and_plots_the_rest(tmp_path: Path) -> None:
    # One message with a 401-digit integer (or nested too deeply) ended the reading there:
    # "was not closed (no summary)", 50 of 199 points plotted, exit 0.
    from mcap.writer import Writer

    path = tmp_path / "run.mcap"
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema("t", "jsonschema", b"{}")
        channel = writer.register_channel("/board/L/telemetry", "json", schema)
        for i in range(199):
            if i == 50:
                data = b'{"a_speed": 1' + b"0" * 400 + b"}"
            elif i == 120:
                data = b'{"a_speed": ' + b"[" * 50_000 + b"]" * 50_000 + b"}"
            else:
                data = json.dumps({"a_speed": float(i)}).encode()
            writer.add_message(channel, log_time=i * 1_000_000, data=data,
                               publish_time=i * 1_000_000)
        writer.finish()  # type: ignore[no-untyped-call]
    out = tmp_path / "run.png"
    done = run_cli("plot", str(path), "--fields", "a.speed", "-o", str(out))
    assert done.returncode == 0, done.stderr
    assert "was not closed" not in done.stderr
    assert "skipped 2 message(s)" in done.stderr
    assert "plotted 197 points" in done.stderr
