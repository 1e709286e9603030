"""Each benchmark still runs end to end with ``--quick`` and writes a report of the shape the
README's figures are read from.

Speeds are never checked: they belong to the machine, and a loaded CI runner would make such
a test flaky. What would silently rot is the scripts themselves as the API under them
changes, and their bookkeeping: so the counts a script reports must add up (every message
sent is received or counted lost, none lost on the in-memory paths).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.benchmark_smoke

REPO = Path(__file__).resolve().parents[2]
#: Generous: a quick run takes seconds, but a busy machine may stretch the emulator start-ups.
TIMEOUT_S = 100
HEADER = ("benchmark", "created", "machine", "python", "packages", "config")
SUMMARY = {"median", "min", "max"}


def run_quick(name: str, tmp_path: Path, *extra: str) -> tuple[str, dict[str, Any]]:
    """``python -m benchmarks.<name> --quick`` from the repository root, as ``make bench``
    runs it; its stdout and its JSON report (written to ``tmp_path``, so a smoke run never
    overwrites a real run's ``benchmarks/results/<name>.json``)."""
    out = tmp_path / f"{name}.json"
    proc = subprocess.run(
        [sys.executable, "-m", f"benchmarks.{name}", "--quick", "--output", str(out), *extra],
        cwd=REPO, capture_output=True, text=True, timeout=TIMEOUT_S, check=False,
    )
    assert proc.returncode == 0, f"stdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    report = json.loads(out.read_text(encoding="utf-8"))
    for key in HEADER:
        assert key in report, key
    assert report["benchmark"] == name
    assert report["config"]["quick"] is True
    assert report["packages"]["fpgalink"]
    machine = report["machine"]
    assert machine["cpu_model"] and machine["cpu_count"]
    # The figures are printed beside the machine that produced them.
    assert machine["cpu_model"] in proc.stdout
    assert str(out) in proc.stdout
    return proc.stdout, report


def assert_summary(summary: dict[str, Any], *metrics: str) -> None:
    for metric in metrics:
        assert set(summary[metric]) == SUMMARY, metric
        assert summary[metric]["min"] <= summary[metric]["median"] <= summary[metric]["max"]


@pytest.mark.timeout(TIMEOUT_S + 20)
def test_codec_quick(tmp_path: Path) -> None:
    stdout, report = run_quick("codec", tmp_path)
    assert "frames/s" in stdout
    assert report["config"]["reps"] == 1
    assert set(report["streams"]) == {"tm", "counted190", "escaped52", "escaped190"}

    message_paths = ("decode.typed", "decode.connection", "encode.connection")
    framing_paths = ("decode.framing", "decode.naive", "encode.framing", "encode.naive")
    expected = {f"{s}.{p}" for s in ("tm", "counted190") for p in framing_paths + message_paths}
    expected |= {f"{s}.{p}" for s in ("escaped52", "escaped190") for p in framing_paths}
    assert set(report["cases"]) == expected
    for key, case in report["cases"].items():
        assert case["frames"] > 0 and case["wire_bytes"] > 0, key
        (rep,) = case["repetitions"]
        assert rep["frames_handled"] == case["frames"], key
        assert_summary(case["summary"], "frames_per_s", "mb_per_s", "line_rate_x", "seconds")

    # Every path has its ratio to the naive model of the same operation, from this run.
    assert set(report["ratios_vs_naive"]) == {k for k in expected if not k.endswith(".naive")}
    for key, ratio in report["ratios_vs_naive"].items():
        assert ratio["baseline"] == key.rsplit(".", 1)[0] + ".naive"
        assert ratio["median"] > 0
    for target in report["targets"]:
        assert isinstance(target["pass"], bool) and target["case"] in report["cases"]
    # Issue 17's ratios to the naive decoder, each a row of the target table.
    ratio_targets = {t["case"] for t in report["targets"] if t["metric"].startswith("×")}
    assert ratio_targets == {"tm.decode.framing", "escaped52.decode.framing",
                             "escaped190.decode.framing"}
    assert "PASS" in stdout or "FAIL" in stdout


@pytest.mark.timeout(TIMEOUT_S + 20)
def test_emulator_quick(tmp_path: Path) -> None:
    stdout, report = run_quick("emulator", tmp_path)
    assert "× real time" in stdout
    config = report["config"]
    assert config["reps"] == 1 and config["emulated_s"] == 1.0
    builds = config["builds"]
    # Both builds where the compiled one is installed (make test: required), else pure.
    assert builds in (["compiled", "pure"], ["pure"])
    if os.environ.get("FPGALINK_REQUIRE_COMPILED") == "1":
        assert builds == ["compiled", "pure"]

    assert set(report["cases"]) == {"board", "board+host", "board.tm_only", "board.idle",
                                    "robot", "robot.mujoco"}
    idle = report["cases"].pop("board.idle")
    for build in builds:
        (rep,) = idle[build]["repetitions"]
        assert rep["periods"] == 10_000 and rep["tm_sent"] == 0 and rep["missed"] == 0
    for key, case in report["cases"].items():
        boards = 2 if key.startswith("robot") else 1
        assert (case["compiled_over_pure"] is not None) == (len(builds) == 2), key
        counted = [case[build]["repetitions"][0] for build in builds]
        # Both builds did the same work, to the message.
        assert all(rep == {**counted[0], "wall_s": rep["wall_s"], "cpu_s": rep["cpu_s"]}
                   for rep in counted), key
        rep = counted[0]
        assert rep["periods"] == 1000 and rep["missed"] == 0, key
        assert rep["tm_dropped"] == 0, key
        # Every period queued its TM; the last may still be on the wire when the run ends.
        assert rep["tm_sent"] == rep["periods"] * boards, key
        assert rep["tm_sent"] - boards <= rep["tm_finished"] <= rep["tm_sent"], key
        assert rep["rv_handled"] == rep["rv_sent"], key
        # robot: 2 × 100
        expected_rv = {"board.tm_only": 0, "robot": 200, "robot.mujoco": 200}.get(key, 1000)
        assert rep["rv_sent"] == expected_rv, key
        for build in builds:
            assert_summary({"x_real_time": case[build]["x_real_time"],
                            "events_per_s": case[build]["events_per_s"]},
                           "x_real_time", "events_per_s")
        if key == "board+host":
            # In memory nothing can be lost: every TM the board finished is decoded.
            assert rep["tm_received"] == rep["tm_finished"], key
            assert rep["tm_lost"] == 0 and rep["decode_errors"] == 0, key
        else:
            assert rep["tm_received"] is None, key
    assert report["ceiling"]["us_per_ms"] > 0
    assert [t["case"] for t in report["targets"]][:4] == ["board", "board.idle", "robot",
                                                          "robot.mujoco"]
    assert all(isinstance(t["pass"], bool) for t in report["targets"])


@pytest.mark.timeout(TIMEOUT_S + 20)
def test_instructions_quick(tmp_path: Path) -> None:
    if shutil.which("valgrind") is None or shutil.which("callgrind_control") is None:
        pytest.skip("valgrind (callgrind) is not installed")
    stdout, report = run_quick("instructions", tmp_path)
    assert "instructions per emulated millisecond" in stdout
    board = report["cases"]["board"]
    # A count for each build, of the run alone: a millisecond of a board's work is tens of
    # thousands of instructions at least, and the same work on either build.
    for build in ("compiled", "pure"):
        assert board[build]["per_emulated_ms"] > 10_000, build
    if report["compiled_build_present"]:
        assert board["pure_over_compiled"] > 1.0
    assert report["cases"]["flat loop (+ RV)"]["pure"]["per_emulated_ms"] > 10_000


@pytest.mark.timeout(TIMEOUT_S + 20)
def test_link_quick(tmp_path: Path) -> None:
    stdout, report = run_quick("link", tmp_path)
    assert "set_param round trip p50" in stdout and "host CPU per TM" in stdout
    assert report["config"]["sets"] == 100 and report["config"]["seconds"] == 3.0
    assert report["serve"]["exit_code"] == 0

    sets = report["set_param"]
    assert sets["count"] == 100
    assert 0 < sets["p50_us"] <= sets["p99_us"] <= sets["max_us"]

    tm = report["telemetry"]
    assert tm["received"] > 0
    # The link's own count and the listener's agree, and every counter between the first
    # and the last TM seen was either seen or counted missing. Loss itself is not asserted:
    # a starved machine can overflow a pty, and that is the machine, not the code.
    assert tm["listener_received"] == tm["received"]
    assert tm["received"] + tm["missing_counters"] == tm["counter_span"]
    for key in ("lost", "counter_gaps", "missing_counters", "subscriber_drops"):
        assert isinstance(tm[key], int) and tm[key] >= 0, key
    for key in ("interarrival_p50_ms", "interarrival_p99_ms", "jitter_p50_ms", "jitter_p99_ms",
                "cpu_us_per_tm", "host_cpu_s", "idle_wakeup_cpu_us"):
        assert tm[key] >= 0, key

    batched = report["telemetry_batched"]
    assert batched["received"] > 0 and batched["read_latency_s"] == 0.01
    assert batched["listener_received"] == batched["received"]
    assert batched["received"] + batched["missing_counters"] == batched["counter_span"]
    assert batched["set_param_while_batching_us"] > 0

    assert {t["name"] for t in report["targets"]} == {
        "tm.lost", "tm.cpu_us_per_tm", "tm.cpu_us_per_tm_above_idle", "tm_batched.lost",
        "tm_batched.cpu_us_per_tm", "set_param.p50_us", "set_param.p99_us"}
    for target in report["targets"]:
        assert isinstance(target["pass"], bool) and isinstance(target["required"], bool)


@pytest.mark.timeout(TIMEOUT_S + 20)
def test_throughput_quick(tmp_path: Path) -> None:
    stdout, report = run_quick("throughput", tmp_path, "--no-progress")
    assert "msg/s" in stdout
    for section in ("codec", "host_stack", "paced_1_board", "paced_2_boards", "payload_limit",
                    "timing"):
        assert section in report, section
    assert report["config"]["reps"] == 1

    codec = report["codec"]
    impls = ["fpgalink"] + (["pymavlink"] if codec["pymavlink"]["available"] else [])
    kinds = ("tm", "rv", "ps")
    # TM is decoded twice: through Connection, and by the protocol layer alone.
    assert set(codec["cases"]) == {
        f"{k}.{op}.{impl}" for k in kinds for op in ("encode", "decode") for impl in impls
    } | {"tm.decode_typed.fpgalink"}
    for key, case in codec["cases"].items():
        assert case["messages"] > 0 and case["wire_bytes"] > 0, key
        (rep,) = case["repetitions"]
        assert rep["messages_handled"] == case["messages"], key
        assert_summary(case["summary"], "messages_per_s", "mb_per_s")
    if "pymavlink" in impls:
        assert set(codec["ratios_fpgalink_over_pymavlink"]) == {
            f"{k}.{op}" for k in kinds for op in ("encode", "decode")} | {"tm.decode_typed"}
        # Issue 17's targets against pymavlink, with their verdicts printed.
        assert [t["case"] for t in codec["targets"]] == ["tm.decode_typed", "tm.decode"]
        for target in codec["targets"]:
            assert isinstance(target["pass"], bool)
            assert target["name"] in stdout
        for kind in ("TM", "RV", "PS/PA"):
            peer = codec["pymavlink"][kind]
            # The comparison is only fair at the same payload size.
            assert peer["payload_bytes_max"] == peer["ours_payload_bytes"], kind

    stack = report["host_stack"]["cases"]
    assert set(stack) == {"tm.bulk", "tm.per_frame"}
    for key, case in stack.items():
        (rep,) = case["repetitions"]
        # In memory: every message sent arrives at the subscriber.
        assert rep["sent"] == case["messages"] and rep["delivered"] == rep["sent"], key
        assert rep["lost"] == rep["subscriber_drops"] == rep["decode_errors"] == 0, key
        assert_summary(case["summary"], "messages_per_s", "cpu_us_per_message")

    for section, boards in (("paced_1_board", 1), ("paced_2_boards", 2)):
        paced = report[section]
        assert paced["boards"] == boards and len(paced["board_names"]) == boards
        assert paced["emulator_exit_code"] == 0, paced["emulator_stderr"]
        (rep,) = paced["repetitions"]
        assert set(rep["boards"]) == set(paced["board_names"])
        for name, board in rep["boards"].items():
            assert board["tm_received"] > 0, (section, name)
            # Every counter between the first and last sample is received or missing;
            # loss over a pty is the machine's, so it is counted, not asserted zero.
            assert board["tm_received"] + board["counters_missing"] == board["counter_span"]
            assert board["lost"] >= 0 and board["subscriber_drops"] >= 0
        assert paced["summary"]["lost_total"] == sum(b["lost"] for b in rep["boards"].values())
        assert_summary(paced["summary"], "tm_per_s_total", "host_cpu_percent")

    limit = report["payload_limit"]
    assert 0 < limit["largest_payload_bytes_all_escaped"] < limit["largest_payload_bytes"]


def _ros2_missing() -> str | None:
    import importlib.util

    if importlib.util.find_spec("rclpy") is None:
        return "rclpy is not installed (the ros2 extra)"
    from tests.ros2.test_ros2 import NETNS

    probe = subprocess.run([str(NETNS), "true"], capture_output=True, text=True, check=False)
    return None if probe.returncode == 0 else f"no network namespace: {probe.stderr.strip()}"


@pytest.mark.timeout(TIMEOUT_S + 20)
def test_ros2_quick(tmp_path: Path) -> None:
    import os

    missing = _ros2_missing()
    if missing is not None:
        if os.environ.get("FPGALINK_REQUIRE_ROS2") == "1":
            pytest.fail(missing)
        pytest.skip(missing)
    _, report = run_quick("ros2", tmp_path)
    results = report["results"]
    assert [r["rate_hz"] for r in results] == [100.0, 1000.0]
    for result in results:
        assert result["messages"] > 0
        # Never faster than the rate asked for (a slow machine may deliver fewer).
        assert result["messages"] <= result["rate_hz"] * (result["window_s"] + 0.1)
        assert set(result["cpu_percent"]) == {"node", "serve", "peer"}
        # The stamps were tied to board ticks with no pairing in disagreement.
        assert result["matched"] > 0 and result["mismatched"] == 0
        latency = result["latency_ms"]
        assert latency["p50"] <= latency["p99"] <= latency["max"]


@pytest.mark.timeout(TIMEOUT_S + 20)
def test_crc_ber_quick(tmp_path: Path) -> None:
    stdout, report = run_quick("crc_ber", tmp_path)
    assert "accepted corrupt" in stdout
    assert set(report["cases"]) == {"ber1e-05.plain", "ber1e-05.crc", "ber0.0001.plain",
                                    "ber0.0001.crc"}
    for key, case in report["cases"].items():
        for model in ("fast_model", "emulator"):
            tally = case[model]
            assert tally["frames"] > 0, key
            # every delivered frame is counted once, corrupt or not
            assert tally["accepted_corrupt"] <= tally["delivered"] <= tally["frames"], key
        fast = case["fast_model"]
        assert fast["damaged"] > 0, key  # the line did damage frames at these rates
        if case["crc"]:
            # the CRC catches every damaged frame the quick run makes (2^-16 would pass)
            assert fast["accepted_corrupt"] == 0 and fast["crc_failures"] > 0, key
        else:
            assert fast["accepted_corrupt"] > 0, key  # without it, some get through


@pytest.mark.timeout(TIMEOUT_S + 20)
def test_flood_quick(tmp_path: Path) -> None:
    stdout, report = run_quick("flood", tmp_path)
    assert "every byte" in stdout
    assert set(report["cases"]) == {"pty", "tcp"}
    for where, case in report["cases"].items():
        assert case["exit_code"] == 0, where
        # Every byte of the flood reached the board, none discarded, and the request after
        # it was answered no sooner than the line could carry them.
        assert case["every_byte_delivered"], (where, case["board"])
        assert case["board"]["discarded"] == 0 and case["board"]["held_back"] >= 1, where
        assert case["answer_s"] >= case["line_s"], where
        assert case["rss_peak_kb"] >= case["rss_before_kb"] > 0, where


@pytest.mark.timeout(TIMEOUT_S + 20)
def test_seed_table_quick(tmp_path: Path) -> None:
    pytest.importorskip("mujoco")
    stdout, report = run_quick("seed_table", tmp_path)
    assert "§3.6.7" in stdout and "odometry" in stdout
    assert set(report["table"]) == {
        "gravel-0/50-rate", "gravel-0/50-radius", "gravel-50/-50-rate", "gravel-15/50-rate",
        "gravel-25/50-radius", "marble-70/-70-rate"}
    for row in report["table"].values():
        assert {"seed", "kinematic", "mujoco", "mujoco_fields"} <= set(row)
        assert len(row["mujoco_fields"]) in (1, 3)
    assert 0 <= report["step_halved"]["largest"] < 1
    assert len(report["wander_60s"]) == 3
    assert {"ratio", "front_load_n", "rear_load_n"} <= set(report["slope"])
    assert {"ax_on_stair", "az_on_stair", "max_pitch_deg"} <= set(report["stairs"])
    bodies = {o["body"] for o in report["odometry"].values()}
    assert bodies == {"kinematic", "mujoco"}


@pytest.mark.timeout(TIMEOUT_S + 60)
def test_faults_quick(tmp_path: Path) -> None:
    stdout, report = run_quick("faults", tmp_path)
    assert "host frozen 0.4 s" in stdout
    assert set(report["cases"]) == {"restart", "telemetry loss", "board silent",
                                    "host frozen"}
    for name in ("restart", "telemetry loss", "board silent"):
        (run,) = report["cases"][name]["repetitions"]
        # Cycle-exact on the boards: the robot stopped after the fault, and the other
        # board's enable fell after it too (the robot's RD), whatever the machine's load.
        assert run["stopped_ms"] > 0 and run["other_board_disabled_ms"] > 0, (name, run)
    (frozen,) = report["cases"]["host frozen"]["repetitions"]
    # The boards' own watchdog, 300 ms after the last RE on their clock; the CLI said why.
    assert frozen["watchdog_after_last_re_ms"] == pytest.approx(300.0, abs=0.01)
    assert frozen["exit_code"] == 7 and frozen["said_why"] == 1.0


@pytest.mark.timeout(TIMEOUT_S + 20)
def test_router_quick(tmp_path: Path) -> None:
    stdout, report = run_quick("router", tmp_path)
    assert "router CPU %" in stdout
    direct, *routed = report["rows"]
    assert direct["observers"] is None and direct["router_cpu_percent"] is None
    assert [r["observers"] for r in routed] == report["config"]["observers"]
    for row in [direct, *routed]:
        assert row["requests"] > 0 and row["tm_in_window"] > 0, row
        assert row["rtt_ms"]["min"] <= row["rtt_ms"]["median"] <= row["rtt_ms"]["max"]
    for row in routed:
        # Every observer got every TM the controller got, whatever the machine's load (the
        # router drops only for a client that leaves its buffer full, which these read).
        assert row["router_dropped_frames"] == 0 and set(row["observers_missing_tm"]) <= {0}
        assert row["router_cpu_percent"] > 0


@pytest.mark.timeout(TIMEOUT_S + 60)
def test_campaign_quick(tmp_path: Path) -> None:
    stdout, report = run_quick("campaign", tmp_path)
    assert "per-scenario overhead" in stdout
    # Wall times depend on the machine; that every way gave the same table does not.
    for label, way in report["ways"].items():
        assert way["same"] is True and way["failed"] == 0, label
    assert report["overhead_s_per_scenario"] > 0


@pytest.mark.timeout(TIMEOUT_S + 60)
def test_ceiling_quick(tmp_path: Path) -> None:
    stdout, report = run_quick("ceiling", tmp_path)
    assert "flat loop" in stdout
    assert set(report["cases"]) == {"arithmetic", "+ TM", "+ RV", "board"}
    assert all(case["us_per_ms"] > 0 for case in report["cases"].values())


def test_recording_quick(tmp_path: Path) -> None:
    stdout, report = run_quick("recording", tmp_path)
    assert "silently different" in stdout
    flips = report["config"]["flips"]
    for reader, outcomes in report["flips"].items():
        assert sum(outcomes.values()) == flips, reader  # every flip counted once
    # fpgalink's reader never takes a damaged chunk for a whole one
    assert report["flips"]["fpgalink"].get("silently different", 0) == 0
    assert set(report["speed"]) == {"mcap", "mcap+crc", "fpgalink"}


@pytest.mark.timeout(TIMEOUT_S + 20)
def test_identity_quick(tmp_path: Path) -> None:
    out, report = run_quick("identity", tmp_path)
    results = report["results"]
    assert results["answers IQ"]["answered"] is True
    assert results["seed protocol"]["answered"] is False  # asked three rounds, no answer
    for case in results.values():
        assert_summary(case, "identify_s", "pg_round_trip_s")
    assert "seed protocol" in out
