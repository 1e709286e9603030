"""Every input the fuzzer ever crashed on is replayed here; plus a short bounded atheris run."""

from __future__ import annotations

import importlib
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

HERE = Path(__file__).parent
ROOT = HERE.parents[1]


def _check() -> Callable[[bytes], None]:
    # Import lazily: the harness imports atheris, which only the fuzz run needs.
    pytest.importorskip("atheris")
    harness = importlib.import_module("tests.fuzz.fuzz_codec")
    check: Callable[[bytes], None] = harness.check
    return check


@pytest.mark.parametrize(
    "path", sorted((HERE / "regressions").glob("*")), ids=lambda p: p.name
)
def test_regression_inputs(path: Path) -> None:
    _check()(path.read_bytes())


@pytest.mark.timeout(120)
def test_short_fuzz_run(tmp_path: Path) -> None:
    pytest.importorskip("atheris")
    result = subprocess.run(
        [sys.executable, "-m", "tests.fuzz.fuzz_codec", "-runs=20000", "-seed=1",
         f"-artifact_prefix={tmp_path}/"],
        capture_output=True, text=True, timeout=110, cwd=ROOT,
    )
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    assert "Done 20000 runs" in result.stderr
