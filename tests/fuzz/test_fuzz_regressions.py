"""Every input the fuzzer ever crashed on is replayed here; plus a short bounded atheris run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE.parent))


def _check() -> object:
    # Import lazily: the harness imports atheris, which only the fuzz run needs.
    atheris = pytest.importorskip("atheris")
    del atheris
    sys.path.insert(0, str(HERE))
    import fuzz_codec

    return fuzz_codec.check


@pytest.mark.parametrize(
    "path", sorted((HERE / "regressions").glob("*")), ids=lambda p: p.name
)
def test_regression_inputs(path: Path) -> None:
    _check()(path.read_bytes())  # type: ignore[operator]


@pytest.mark.timeout(120)
def test_short_fuzz_run(tmp_path: Path) -> None:
    pytest.importorskip("atheris")
    result = subprocess.run(
        [sys.executable, str(HERE / "fuzz_codec.py"), "-runs=20000", "-seed=1",
         f"-artifact_prefix={tmp_path}/"],
        capture_output=True, text=True, timeout=110,
    )
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    assert "Done 20000 runs" in result.stderr
