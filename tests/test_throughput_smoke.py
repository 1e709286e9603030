"""The throughput benchmark still runs end to end (emulator subprocesses included) and its
JSON report has every section.

Speeds are not checked: they belong to the machine, and a loaded CI runner would make such a
test flaky. What would silently rot is the script itself as the API under it changes.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "throughput.py"

SECTIONS = ("machine", "python", "packages", "config", "codec", "host_stack", "paced_1_board",
            "paced_2_boards", "payload_limit", "timing")
KINDS = ("tm", "rv", "ps")


@pytest.mark.timeout(90)
def test_throughput_benchmark_quick(tmp_path: Path) -> None:
    out = tmp_path / "throughput.json"
    # --output keeps the smoke run from overwriting a real run's results/throughput.json.
    proc = subprocess.run(
        [sys.executable, str(BENCH), "--quick", "--no-progress", "--output", str(out)],
        capture_output=True, text=True, timeout=90, check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert "msg/s" in proc.stdout and str(out) in proc.stdout

    report = json.loads(out.read_text(encoding="utf-8"))
    for section in SECTIONS:
        assert section in report, section
    assert report["config"]["quick"] is True
    assert report["config"]["reps"] == 1
    assert report["packages"]["fpgalink"]

    codec = report["codec"]
    impls = ["fpgalink"] + (["pymavlink"] if codec["pymavlink"]["available"] else [])
    expected = {f"{k}.{op}.{impl}" for k in KINDS for op in ("encode", "decode") for impl in impls}
    assert set(codec["cases"]) == expected
    for key, case in codec["cases"].items():
        assert case["messages"] > 0 and case["wire_bytes"] > 0, key
        assert len(case["repetitions"]) == 1, key
        for metric in ("messages_per_s", "mb_per_s"):
            assert set(case["summary"][metric]) == {"median", "min", "max"}, (key, metric)
    if "pymavlink" in impls:
        assert set(codec["ratios_fpgalink_over_pymavlink"]) == {
            f"{k}.{op}" for k in KINDS for op in ("encode", "decode")}
        for kind in ("TM", "RV", "PS/PA"):
            peer = codec["pymavlink"][kind]
            # The comparison is only fair at the same payload size.
            assert peer["payload_bytes_max"] == peer["ours_payload_bytes"], kind

    stack = report["host_stack"]["cases"]
    assert set(stack) == {"tm.bulk", "tm.per_frame"}
    for key, case in stack.items():
        assert set(case["summary"]) == {"messages_per_s", "cpu_us_per_message"}, key

    for section, boards in (("paced_1_board", 1), ("paced_2_boards", 2)):
        paced = report[section]
        assert paced["boards"] == boards and len(paced["board_names"]) == boards
        assert len(paced["repetitions"]) == 1
        summary = paced["summary"]
        for key in ("tm_per_s_total", "latency_ms_p50", "latency_ms_p99", "host_cpu_percent"):
            assert set(summary[key]) == {"median", "min", "max"}, (section, key)
        assert isinstance(summary["lost_total"], int)
        for name in paced["board_names"]:
            assert summary["boards"][name]["tm_per_s"]["median"] > 0, (section, name)

    limit = report["payload_limit"]
    assert 0 < limit["largest_payload_bytes_all_escaped"] < limit["largest_payload_bytes"]
