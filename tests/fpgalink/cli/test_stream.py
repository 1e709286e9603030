"""``monitor`` and ``record`` end to end, including Ctrl-C (SIGINT) mid-run."""

from __future__ import annotations

import csv
import io
import itertools
import json
import signal
from pathlib import Path

import pytest
from mcap.reader import make_reader

from fpgalink.boardclock import MAX_SLEW
from fpgalink.recording import partial_path
from tests.support.cli import Board, run_cli, start_cli
from tests.support.waiting import wait_until_sync as wait_until

pytestmark = pytest.mark.timeout(60)


def read_mcap(path: Path) -> dict[str, list[dict[str, object]]]:
    topics: dict[str, list[dict[str, object]]] = {}
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None  # finish() wrote the summary: the file is complete
        for schema, channel, message in reader.iter_messages():
            assert schema is not None and schema.encoding == "jsonschema"
            assert channel.message_encoding == "json"
            topics.setdefault(channel.topic, []).append(json.loads(message.data))
    return topics


def test_monitor_csv_stream(board: Board) -> None:
    done = run_cli("monitor", "--duration", "0.6", "--format", "csv", "--port", board.url)
    assert done.returncode == 0, done.stderr
    rows = list(csv.DictReader(io.StringIO(done.stdout)))
    assert len(rows) >= 5
    assert {"board", "timestamp", "a_speed", "b_pwm", "a_flags"} <= set(rows[0])
    assert float(rows[-1]["timestamp"]) > float(rows[0]["timestamp"])
    if board.fake is not None:  # telemetry was switched back off on the way out
        assert board.fake.script.values[(2, 0)] == 0


def test_monitor_jsonl_two_named_boards(board: Board) -> None:
    if board.kind == "pty":
        pytest.skip("one pty serves one host at a time")
    done = run_cli("monitor", "--duration", "0.6", "--format", "jsonl",
                   "--port", f"L={board.url}", "--port", f"R={board.url}")
    assert done.returncode == 0, done.stderr
    rows = [json.loads(line) for line in done.stdout.splitlines()]
    assert {r["board"] for r in rows} == {"L", "R"}
    assert all(isinstance(r["a_speed"], float) for r in rows)


def test_monitor_table_shows_both_channels_and_link(board: Board) -> None:
    done = run_cli("monitor", "--duration", "0.8", "--format", "table", "--port", board.url)
    assert done.returncode == 0, done.stderr
    for text in ("Telemetry", "speed deg/s", "Link", "TM/s", "heartbeats", "alive"):
        assert text in done.stdout


def test_record_mcap_has_telemetry_params_and_events(board: Board, tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    done = run_cli("record", str(path), "--duration", "1.2", "--port", board.url)
    assert done.returncode == 0, done.stderr
    assert "recorded" in done.stderr
    topics = read_mcap(path)
    telemetry = topics["/board/0/telemetry"]
    assert len(telemetry) >= 10
    assert {"timestamp", "t_us", "a_speed", "b_current", "a_pwm"} <= set(telemetry[0])
    names = {p["name"] for p in topics["/board/0/params"]}
    assert {"TsTimerPeriod", "Kp_Wheel_PidA", "GetDataPeriodical"} <= names  # snapshot
    events = topics["/board/0/events"]  # foxglove.Log, so Foxglove's Log panel shows them
    assert {"timestamp", "level", "message", "name", "file", "line"} <= set(events[0])
    kinds = [str(e["message"]).split(":")[0] for e in events]
    assert kinds[0] == "recording_started" and kinds[-1] == "recording_stopped"
    assert all(e["name"] == "0" for e in events)
    assert topics["/board/0/stats"]


def test_record_csv(board: Board, tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    done = run_cli("record", str(path), "--csv", "--duration", "0.5", "--port", board.url)
    assert done.returncode == 0, done.stderr
    rows = list(csv.DictReader(path.open(encoding="utf-8")))
    assert len(rows) >= 5 and "a_speed" in rows[0]


def test_ctrl_c_stops_record_cleanly_with_a_valid_file(board: Board, tmp_path: Path) -> None:
    path = tmp_path / "interrupted.mcap"
    proc = start_cli("record", str(path), "--port", board.url)
    try:
        # Poll for real progress (the file grows as chunks are written, under its partial
        # name until it is complete) rather than sleep.
        partial = partial_path(path)
        wait_until(lambda: proc.poll() is not None or (partial.exists() and
                                                        partial.stat().st_size > 4000),
                   timeout=15, what="record to write telemetry")
        assert not path.exists()
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    topics = read_mcap(path)  # in place, complete
    assert not partial.exists()
    assert len(topics["/board/0/telemetry"]) > 0
    assert topics["/board/0/events"][-1]["message"] == "recording_stopped"


def test_ctrl_c_stops_monitor_with_130(board: Board) -> None:
    proc = start_cli("monitor", "--format", "jsonl", "--port", board.url)
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()  # blocks until the first sample: the stream is live
        assert json.loads(first)["board"] == "0"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err


def test_record_clocks_mean_what_mcap_says(tmp_path: Path) -> None:
    # log_time: when the host received the message; publish_time: the board's sample time
    # on the host clock (the payload's timestamp); raw t_us kept.
    path = tmp_path / "clocks.mcap"
    done = run_cli("record", str(path), "--duration", "1.0", "--port", "emu://")
    assert done.returncode == 0, done.stderr
    with path.open("rb") as f:
        samples = [(m.log_time, m.publish_time, json.loads(m.data))
                   for _, c, m in make_reader(f).iter_messages()
                   if c.topic == "/board/0/telemetry"]
    assert len(samples) > 100
    assert any(log != pub for log, pub, _ in samples)  # two clocks, not one copied
    for log, pub, row in samples:
        assert abs(pub - row["timestamp"] * 1e9) < 2e3  # the payload's time, to its 1 µs
        assert abs(log - pub) < 1e9  # the same epoch, apart by transport and drift only
    # publish_time advances as board time does, less what the mapping's offset slewed down
    # while the first sample's delay was worked off (fpgalink.boardclock: at most MAX_SLEW
    # of the board time passed; a drift is estimated only from 10 s on).
    for (_, pub0, row0), (_, pub1, row1) in itertools.pairwise(samples):
        board_us = row1["t_us"] - row0["t_us"]
        assert (1 - MAX_SLEW) * board_us - 2 <= (pub1 - pub0) / 1e3 <= board_us + 2
    (first_log, pub0, row0), (_, pub1, row1) = samples[0], samples[-1]
    assert first_log == pub0  # the first sample is stamped when it arrived
    span_us = row1["t_us"] - row0["t_us"]
    assert -2 <= span_us - (pub1 - pub0) / 1e3 <= MAX_SLEW * span_us
