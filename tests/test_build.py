"""Which build runs (``fpgalink.buildinfo``): the compiled one only when every compiled
module's source is the one it was compiled from. A copy of this checkout's compiled tree is
edited, touched or stripped of its manifest, and a child interpreter on it must run the
source (saying so) or the extensions, as each case asks; ``FPGALINK_PURE=1`` runs pure
Python; and the builder falls back to pure Python, saying why, without a C compiler."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from importlib.machinery import EXTENSION_SUFFIXES
from pathlib import Path

import pytest

import fpgaemu.timeline
from fpgalink.buildinfo import BUILD, COMPILED

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
PROBE = ("import fpgaemu.timeline as t, fpgalink.buildinfo as b\n"
         "print(b.BUILD, '|', t.__file__, '|', getattr(t, 'EDITED', None))\n")


def _compiled_here() -> None:
    """Skip where this checkout has no compiled build (whichever build this process runs:
    the copies are probed without ``FPGALINK_PURE``)."""
    if (SRC / "fpgalink" / "_compiled.txt").exists():
        return
    if os.environ.get("FPGALINK_REQUIRE_COMPILED") == "1":
        pytest.fail("the compiled build must run here (FPGALINK_REQUIRE_COMPILED=1); "
                    "`make compile` builds it")
    pytest.skip("no compiled build in this checkout")


def _copy(tmp_path: Path) -> Path:
    src = tmp_path / "src"
    shutil.copytree(SRC, src, ignore=shutil.ignore_patterns("__pycache__"))
    return src


def _probe(src: Path, *, pure: bool = False) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "FPGALINK_PURE"}
    env["PYTHONPATH"] = str(src)
    if pure:
        env["FPGALINK_PURE"] = "1"
    return subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                          env=env, cwd=src.parent, timeout=60, check=True)


def test_this_process_runs_the_build_it_was_asked_for() -> None:
    if os.environ.get("FPGALINK_PURE", "") not in ("", "0"):
        assert BUILD == "pure Python" and not COMPILED
        assert fpgaemu.timeline.__file__ is not None
        assert fpgaemu.timeline.__file__.endswith(".py")
        return
    _compiled_here()
    assert BUILD.startswith("compiled") and "fpgaemu.board" in COMPILED
    assert fpgaemu.timeline.__file__ is not None
    assert fpgaemu.timeline.__file__.endswith(tuple(EXTENSION_SUFFIXES))


def test_a_changed_source_is_never_shadowed_by_its_stale_compiled_module(
        tmp_path: Path) -> None:
    _compiled_here()
    src = _copy(tmp_path)
    with (src / "fpgaemu" / "timeline.py").open("a", encoding="utf-8") as source:
        source.write('\nEDITED = "the edit runs"\n')
    done = _probe(src)
    build, path, edited = done.stdout.strip().split(" | ")
    assert (build, edited) == ("pure Python", "the edit runs")
    assert path.endswith("timeline.py")
    assert "timeline.py changed since the compiled build: running pure Python" in done.stderr
    assert "make compile" in done.stderr


def test_a_source_touched_but_not_changed_keeps_the_compiled_build(tmp_path: Path) -> None:
    _compiled_here()
    src = _copy(tmp_path)
    os.utime(src / "fpgaemu" / "board.py")  # a checkout, an editor saving the same text
    done = _probe(src)
    assert done.stdout.startswith("compiled (mypyc) | ") and not done.stderr


def test_extensions_without_their_manifest_are_not_loaded(tmp_path: Path) -> None:
    _compiled_here()
    src = _copy(tmp_path)
    (src / "fpgalink" / "_compiled.txt").unlink()  # an interrupted build, say
    done = _probe(src)
    assert done.stdout.startswith("pure Python | ") and "timeline.py" in done.stdout
    assert "without their build's manifest" in done.stderr


def test_extensions_without_their_shared_library_are_not_loaded(tmp_path: Path) -> None:
    # The packages copied without the build's library beside them (as a copy of the package
    # directories makes): the extensions would load whatever library of that name is on the
    # path, another build's, and fail at import. They are not loaded: pure Python, said.
    _compiled_here()
    src = _copy(tmp_path)
    for library in src.glob("fpgalink__mypyc*"):
        library.unlink()
    done = _probe(src)
    assert done.stdout.startswith("pure Python | ") and "timeline.py" in done.stdout
    assert "without their build's shared library" in done.stderr
    assert _probe(src, pure=True).stdout.startswith("pure Python | ")  # nor on FPGALINK_PURE


def test_fpgalink_pure_runs_pure_python_and_the_version_says_which(tmp_path: Path) -> None:
    _compiled_here()
    src = _copy(tmp_path)
    assert _probe(src, pure=True).stdout.startswith("pure Python | ")
    env = {k: v for k, v in os.environ.items() if k != "FPGALINK_PURE"}
    env["PYTHONPATH"] = str(src)
    for program, module in (("fpgaemu", "fpgaemu"), ("fpgalink-cli", "fpgalink")):
        for pure, said in ((False, "compiled (mypyc)"), (True, "pure Python")):
            done = subprocess.run([sys.executable, "-m", module, "--version"], text=True,
                                  capture_output=True, timeout=60, check=True, cwd=tmp_path,
                                  env={**env, "FPGALINK_PURE": "1"} if pure else env)
            assert done.stdout.strip() == f"{program}, version 0.2.0, {said}"


def test_without_a_c_compiler_the_build_is_pure_python_and_says_why(tmp_path: Path) -> None:
    root = tmp_path / "checkout"
    (root / "build_support").mkdir(parents=True)
    shutil.copy(ROOT / "build_support" / "mypyc_build.py", root / "build_support")
    shutil.copy(ROOT / "pyproject.toml", root)
    shutil.copytree(SRC, root / "src", ignore=shutil.ignore_patterns("__pycache__"))
    env = {**os.environ, "CC": "no-such-cc"}
    env.pop("FPGALINK_PURE", None)
    done = subprocess.run([sys.executable, str(root / "build_support" / "mypyc_build.py")],
                          capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 1
    assert done.stderr.strip() == ("fpgalink: no compiled build (no C compiler (no-such-cc "
                                   "not found)): pure Python")
    # Nothing compiled is left to be loaded: what an earlier build left went first.
    assert not list((root / "src").rglob("*.so"))
    assert _probe(root / "src").stdout.startswith("pure Python | ")
