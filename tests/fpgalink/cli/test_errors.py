"""Bad input, missing or busy ports, silent and refusing boards: exit code and one line."""

from __future__ import annotations

import os
import socket
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import serial

from fpgalink.protocol import ParamGet
from tests.support.cli import Board, BoardThread, cli_env, run_cli

pytestmark = pytest.mark.timeout(60)


def assert_one_line_error(stderr: str, *needles: str) -> None:
    lines = [li for li in stderr.splitlines() if li.strip()]
    assert len(lines) == 1, stderr
    assert lines[0].startswith("fpgalink-cli: error: "), stderr
    assert "Traceback" not in stderr
    for needle in needles:
        assert needle in lines[0], stderr


@pytest.mark.parametrize(("args", "needles"), [
    (["param", "set", "NoSuchParam", "1"], ["unknown parameter 'NoSuchParam'"]),
    (["param", "get", "Bogus"], ["unknown parameter 'Bogus'"]),
    (["param", "set", "TsTimerPeriod", "0"], ["TsTimerPeriod", "1..1000"]),
    (["param", "set", "TsTimerPeriod", "2.5"], ["TsTimerPeriod", "integer", "1..1000"]),
    (["param", "set", "TsTimerPeriod", "fast"], ["TsTimerPeriod", "'fast'", "1..1000"]),
    (["param", "set", "Kp_Wheel_PidA", "-1"], ["Kp_Wheel_PidA", "≥ 0"]),
    (["param", "set", "Ti_Wheel_Pid", "0", "-c", "B"], ["Ti_Wheel_PidB", "> 0"]),
    (["param", "set", "IncSenzCountDirectionA", "0"], ["IncSenzCountDirectionA", "-1 or 1"]),
    (["param", "set", "Kp_Wheel_Pid", "1"], ["Kp_Wheel_Pid", "channel A or B"]),
    (["param", "set", "Kp_Wheel_PidA", "nan"], ["Kp_Wheel_PidA", "≥ 0"]),
    (["send", "E1"], ["reserved"]),
    (["send", "PG", "--hex", "02"], ["PG needs one 2-byte binary section"]),
    (["send", "ZZ", "--hex", "zz"], ["--hex 'zz'"]),
    (["send", "ZZ", "--text", "a{b"], ["'{'"]),
    (["send", "RD", "--text", "x"], ["direct command"]),
])
def test_bad_input_exits_2_and_sends_nothing(
    fake_board: Callable[..., BoardThread], args: list[str], needles: list[str]
) -> None:
    fake = fake_board()
    done = run_cli(*args, "--port", fake.url)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, *needles)
    assert fake.board.received == []  # nothing reached the board


def test_bad_param_file_exits_2(fake_board: Callable[..., BoardThread], tmp_path) -> None:  # type: ignore[no-untyped-def]
    fake = fake_board()
    bad = tmp_path / "bad.toml"
    bad.write_text("TsTimerPeriod = 5\n[A]\nKp_Wheel_Pid = -3.0\n", encoding="utf-8")
    done = run_cli("param", "load", str(bad), "--port", fake.url)
    assert done.returncode == 2
    assert_one_line_error(done.stderr, "Kp_Wheel_PidA", "≥ 0")
    assert fake.board.received == []  # validated as a whole before the first byte


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize("command", [["param", "get", "TsTimerPeriod"], ["monitor"],
                                     ["send", "RD"]])
def test_missing_port_exits_5_naming_it(command: list[str], tmp_path) -> None:  # type: ignore[no-untyped-def]
    for port in (f"socket://127.0.0.1:{_free_tcp_port()}", str(tmp_path / "ttyNONE")):
        done = run_cli(*command, "--duration", "1", "--port", port) if command == ["monitor"] \
            else run_cli(*command, "--port", port)
        assert done.returncode == 5, done.stderr
        assert_one_line_error(done.stderr, port)
        # Issue 41: said once, in words (was: the path and "[Errno 2]" twice each).
        assert done.stderr.count(port) == 1 and "Errno" not in done.stderr, done.stderr
    assert "no such device" in done.stderr


def test_busy_port_exits_5_naming_it() -> None:
    master, slave = os.openpty()
    path = os.ttyname(slave)
    holder = serial.Serial(path, exclusive=True)  # another program has the port
    try:
        for command in (["param", "get", "TsTimerPeriod"], ["router"]):
            done = run_cli(*command, "--port", path)
            assert done.returncode == 5, done.stderr
            # Issue 41: what it means and what to do (was: "[Errno 11] Could not
            # exclusively lock port …: [Errno 11] Resource temporarily unavailable").
            assert_one_line_error(done.stderr, path, "in use by another program; share it "
                                  "with `fpgalink-cli router`")
            assert done.stderr.count(path) == 1 and "Errno" not in done.stderr, done.stderr
    finally:
        holder.close()
        os.close(master)
        os.close(slave)


def test_board_not_answering_exits_4_saying_how_many_tries(
    fake_board: Callable[..., BoardThread]
) -> None:
    fake = fake_board(mute=True)
    done = run_cli("param", "set", "TsTimerPeriod", "5", "--port", fake.url, "--retries", "3",
                   "--timeout", "0.05")
    assert done.returncode == 4, done.stderr
    assert_one_line_error(done.stderr, "not answering", "3 tries")
    # Its first question is who the board is (IQ, then a PG that every board answers):
    # every try of that PG went out, each with its own counter, and nothing was set.
    assert "asking who the board is" in done.stderr
    gets = [m for m in fake.board.received if isinstance(m, ParamGet)]
    assert len(gets) == 3 and len({m.counter for m in gets}) == 3
    assert not [m for m in fake.board.received if type(m).__name__ == "ParamSet"]


def test_send_reply_timeout_exits_4(fake_board: Callable[..., BoardThread]) -> None:
    fake = fake_board(mute=True)
    done = run_cli("send", "PG", "--hex", "0100", "--reply", "PA", "--wait", "0.2",
                   "--port", fake.url)
    assert done.returncode == 4
    assert_one_line_error(done.stderr, "no reply to PG within 0.2 s", "heard: nothing")


def test_refusal_exits_3_with_reason(fake_board: Callable[..., BoardThread]) -> None:
    fake = fake_board(nack=3)
    done = run_cli("param", "set", "TsTimerPeriod", "5", "--port", fake.url)
    assert done.returncode == 3
    assert_one_line_error(done.stderr, "refused", "TsTimerPeriod", "value out of range")


def test_two_ports_for_a_one_board_command_exits_2(board: Board) -> None:
    done = run_cli("param", "get", "TsTimerPeriod", "--port", f"L={board.url}",
                   "--port", f"R={board.url}")
    assert done.returncode == 2
    assert_one_line_error(done.stderr, "one board")


def test_env_port_and_default_emulator_notice(fake_board: Callable[..., BoardThread]) -> None:
    fake = fake_board()
    done = run_cli("param", "get", "TsTimerPeriod", env=cli_env(FPGALINK_PORT=fake.url))
    assert done.returncode == 0, done.stderr
    assert "emulator" not in done.stderr
    # No port anywhere: one line on stderr says the built-in emulator is used.
    done = run_cli("param", "get", "Bogus")
    assert done.returncode == 2
    assert "using the built-in emulator emu://" in done.stderr.splitlines()[0]


def test_help_documents_exit_codes() -> None:
    done = run_cli("--help")
    assert done.returncode == 0
    text = " ".join(done.stdout.split())
    for code in ("2 bad input", "3 board refused", "4 board not answering",
                 "5 port missing, busy or failed (or a file another process is writing now)",
                 "8 an optional part not installed",
                 "9 a recording read is damaged",
                 "130 interrupted"):
        assert code in text


# --- the wire CRC's modes disagreeing (issue 37, item 7) ---------------------------------------

CRC_ON_BOARD = "the board sends CRC-16 frames; connect with the CRC on (--wire-crc"
PLAIN_BOARD = "the board sends frames without the wire CRC; connect with the CRC off"


@pytest.fixture(params=["crc", "plain"])
def streaming_board(request: pytest.FixtureRequest) -> Iterator[tuple[str, str]]:
    """``fpgaemu serve --pty`` streaming telemetry, its wire CRC on or off."""
    from tests.support.serving import served

    crc = ["--set", "WireCrc=1"] if request.param == "crc" else []
    with served("--pty", *crc, "--set", "GetDataPeriodical=1") as server:
        yield request.param, server.url


def test_a_host_in_the_other_wire_crc_mode_says_how_to_connect_and_fails(
        streaming_board: tuple[str, str], tmp_path: Path) -> None:
    # Monitor and record only listening: nothing usable comes (every TM dropped), so each
    # says how to connect and exits 4. They exited 0 with nothing ("recorded 0 telemetry
    # samples"). A command that asks the board who it is at connect ends the question with
    # the wire CRC's handshake, which settles the link in the board's mode: its request is
    # answered (it said "board not answering" while the board's heartbeats arrived).
    kind, pty = streaming_board
    flip = ["--wire-crc"] if kind == "plain" else []
    said = CRC_ON_BOARD if kind == "crc" else PLAIN_BOARD
    runs = [run_cli("--port", pty, *flip, "monitor", "--passive", "--duration", "1",
                    "--format", "csv"),
            run_cli("--port", pty, *flip, "record", "--passive", "--duration", "1",
                    str(tmp_path / "r.mcap"))]
    for done in runs:
        assert done.returncode == 4, done.stdout + done.stderr
        assert "fpgalink-cli: error: board 0: " in done.stderr, done.stderr
        assert said in done.stderr and "Traceback" not in done.stderr, done.stderr
    assert "recorded 0 telemetry samples" in runs[1].stderr
    asked = run_cli("--port", pty, *flip, "param", "get", "TsTimerPeriod")
    assert (asked.returncode, asked.stdout.strip()) == (0, "1"), asked.stderr
    # In the board's mode the same commands get the telemetry and the value.
    mode = ["--wire-crc"] if kind == "crc" else []
    monitor = run_cli("--port", pty, *mode, "monitor", "--passive", "--duration", "1",
                      "--format", "csv")
    assert monitor.returncode == 0 and len(monitor.stdout.splitlines()) > 10, monitor.stderr
    assert said not in monitor.stderr
    get = run_cli("--port", pty, *mode, "param", "get", "TsTimerPeriod")
    assert (get.returncode, get.stdout.strip()) == (0, "1"), get.stderr
