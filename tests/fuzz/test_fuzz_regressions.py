"""Every input a fuzzer ever crashed on is replayed here; plus a short bounded atheris run of
each harness: the codec, the link's event handling, the board's receive path."""

from __future__ import annotations

import importlib
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

HERE = Path(__file__).parent
ROOT = HERE.parents[1]
HARNESSES = ("fuzz_codec", "fuzz_link", "fuzz_board")
#: A harness's regressions live in regressions/<harness>/ (the codec's also at the top).
RUNS = {"fuzz_codec": 20_000, "fuzz_link": 300, "fuzz_board": 300}


def _check(harness: str) -> Callable[[bytes], None]:
    # Import lazily: the harness imports atheris, which only the fuzz run needs.
    pytest.importorskip("atheris")
    module = importlib.import_module(f"tests.fuzz.{harness}")
    check: Callable[[bytes], None] = module.check
    return check


def _regressions() -> list[tuple[str, Path]]:
    cases = [("fuzz_codec", p) for p in sorted((HERE / "regressions").glob("*"))
             if p.is_file()]
    for harness in HARNESSES:
        folder = HERE / "regressions" / harness
        cases += [(harness, p) for p in sorted(folder.glob("*"))] if folder.is_dir() else []
    return cases


@pytest.mark.parametrize(("harness", "path"), _regressions(), ids=lambda v: getattr(v, "name", v))
def test_regression_inputs(harness: str, path: Path) -> None:
    _check(harness)(path.read_bytes())


@pytest.mark.timeout(120)
@pytest.mark.parametrize("harness", HARNESSES)
def test_short_fuzz_run(harness: str, tmp_path: Path) -> None:
    pytest.importorskip("atheris")
    result = subprocess.run(
        [sys.executable, "-m", f"tests.fuzz.{harness}", f"-runs={RUNS[harness]}", "-seed=1",
         "-max_len=4096", f"-artifact_prefix={tmp_path}/"],
        capture_output=True, text=True, timeout=110, cwd=ROOT,
    )
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
