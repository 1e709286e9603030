"""The emulator benchmark still runs end to end and writes every section of its report.

Speeds are not checked (they belong to the machine); what would silently rot is the script
as the emulator's API changes. The script itself checks each run did the scenario: every
period, no missed TM, both wheels at their references.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "emulator.py"
CASES = {"board", "board+host", "board.tm_only"}


@pytest.mark.timeout(60)
def test_emulator_benchmark_quick(tmp_path: Path) -> None:
    out = tmp_path / "emulator.json"
    proc = subprocess.run(
        [sys.executable, str(BENCH), "--quick", "--output", str(out)],
        capture_output=True, text=True, timeout=60, check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert "× real time" in proc.stdout
    assert "target board" in proc.stdout

    report = json.loads(out.read_text(encoding="utf-8"))
    for section in ("benchmark", "created", "machine", "python", "packages", "config",
                    "cases", "targets", "timing"):
        assert section in report, section
    assert report["benchmark"] == "emulator"
    config = report["config"]
    assert config["quick"] is True and config["reps"] == 1
    assert config["emulated_s"] == 1.0 and config["ts_timer_period_ms"] == 1
    assert report["packages"]["fpgalink"]

    assert set(report["cases"]) == CASES
    for key, case in report["cases"].items():
        assert case["periods"] == 1000 and case["missed"] == 0, key
        assert case["events"] >= 2 * case["periods"], key  # at least a tick and a TM each
        assert 54 <= case["tm_wire_bytes_per_period"] <= 57, key
        assert len(case["repetitions"]) == 1, key
        for metric in ("x_real_time", "events_per_s", "seconds"):
            assert set(case["summary"][metric]) == {"median", "min", "max"}, (key, metric)
            assert case["summary"][metric]["median"] > 0, (key, metric)

    (target,) = report["targets"]
    assert target["case"] == "board" and target["required"] is True
    assert target["threshold"] == 20.0
    assert isinstance(target["pass"], bool)
    assert target["pass"] == (target["measured"] >= target["threshold"])
