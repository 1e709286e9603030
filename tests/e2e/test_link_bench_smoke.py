"""``benchmarks/link.py --quick`` still runs end to end against ``fpgaemu serve --pty`` and
writes every section of its report. Speeds are not checked (they belong to the machine)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "link.py"


@pytest.mark.timeout(60)
def test_link_benchmark_quick(tmp_path: Path) -> None:
    out = tmp_path / "link.json"
    proc = subprocess.run(
        [sys.executable, str(BENCH), "--quick", "--output", str(out)],
        capture_output=True, text=True, timeout=60, check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert "set_param round trip p50" in proc.stdout
    assert "host CPU per TM" in proc.stdout

    report = json.loads(out.read_text(encoding="utf-8"))
    for section in ("machine", "python", "packages", "config", "set_param", "telemetry",
                    "serve", "targets"):
        assert section in report, section
    assert report["config"]["quick"] is True
    assert report["config"]["sets"] == 100 and report["config"]["seconds"] == 3.0
    assert report["serve"]["exit_code"] == 0

    sets = report["set_param"]
    assert sets["count"] == 100
    for key in ("p50_us", "p99_us", "max_us", "mean_us"):
        assert sets[key] > 0, key
    assert sets["p50_us"] <= sets["p99_us"] <= sets["max_us"]

    tm = report["telemetry"]
    assert tm["received"] > 0
    for key in ("lost", "counter_gaps", "missing_counters", "subscriber_drops"):
        assert isinstance(tm[key], int), key
    for key in ("interarrival_p50_ms", "interarrival_p99_ms", "jitter_p50_ms",
                "jitter_p99_ms", "cpu_us_per_tm", "host_cpu_s"):
        assert tm[key] >= 0, key

    assert {t["name"] for t in report["targets"]} == {
        "tm.lost", "tm.cpu_us_per_tm", "tm.cpu_us_per_tm_above_idle"}
    for target in report["targets"]:
        assert isinstance(target["pass"], bool) and isinstance(target["required"], bool)
