"""The codec benchmark still runs end to end and writes every section of its report.

Speeds are not checked: they belong to the machine, and a loaded CI runner would make such a
test flaky. What would silently rot is the script itself as the API under it changes.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "codec.py"

STREAMS = {"tm", "counted190", "escaped190"}
CASES = {
    f"{stream}.{op}"
    for stream in ("tm", "counted190")
    for op in (
        "decode.framing", "decode.naive", "decode.typed", "decode.connection",
        "encode.framing", "encode.connection",
    )
} | {"escaped190.decode.framing", "escaped190.decode.naive", "escaped190.encode.framing"}
TARGETS = {"tm.decode.framing", "tm.decode.typed", "escaped190.decode.framing"}


@pytest.mark.timeout(60)
def test_codec_benchmark_quick(tmp_path: Path) -> None:
    out = tmp_path / "codec.json"
    # --output keeps the smoke run from overwriting a real run's results/codec.json.
    proc = subprocess.run(
        [sys.executable, str(BENCH), "--quick", "--output", str(out)],
        capture_output=True, text=True, timeout=60, check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert "frames/s" in proc.stdout

    report = json.loads(out.read_text(encoding="utf-8"))
    for section in ("machine", "python", "packages", "config", "streams", "cases",
                    "ratios_vs_naive", "targets", "timing"):
        assert section in report, section
    assert report["config"]["quick"] is True
    assert report["config"]["reps"] == 1
    assert report["packages"]["fpgalink"]
    assert set(report["streams"]) == STREAMS

    assert set(report["cases"]) == CASES
    for key, case in report["cases"].items():
        assert case["frames"] > 0 and case["wire_bytes"] > 0, key
        assert len(case["repetitions"]) == 1, key
        for metric in ("frames_per_s", "mb_per_s", "line_rate_x", "seconds"):
            assert set(case["summary"][metric]) == {"median", "min", "max"}, (key, metric)

    required = [t for t in report["targets"] if t["required"]]
    assert {t["case"] for t in required} == TARGETS
    for target in report["targets"]:
        assert isinstance(target["pass"], bool)
        assert target["measured"] > 0 and target["threshold"] > 0
