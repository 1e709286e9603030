"""41.16: the demo's install leaves the package and what a command imports byte-compiled, so
start-up does not compile them again where ``PYTHONDONTWRITEBYTECODE=1`` is set (nothing is
ever written at run time there)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

from tests.support.cli import ROOT

PRECOMPILE = ROOT / "tools" / "precompile.py"

#: A child that imports every module of fpgalink and fpgaemu and prints those it had to
#: compile from source (no usable bytecode).
COUNT_COMPILES = """
import importlib, importlib.machinery, json, pkgutil, sys
compiled = []
original = importlib.machinery.SourceFileLoader.source_to_code
def source_to_code(self, data, path, *args, **kwargs):
    compiled.append(path)
    return original(self, data, path, *args, **kwargs)
importlib.machinery.SourceFileLoader.source_to_code = source_to_code
for top in ("fpgalink", "fpgaemu"):
    package = importlib.import_module(top)
    for info in pkgutil.walk_packages(package.__path__, top + "."):
        if ".ros2" in info.name or info.name.endswith(".__main__"):
            continue  # needs ROS 2 / runs a program
        try:
            importlib.import_module(info.name)
        except ImportError:
            pass  # an extra not installed here; its module still compiled or not above
print(json.dumps(compiled))
"""


def _copy_packages(tmp_path: Path) -> Path:
    src = tmp_path / "src"
    for name in ("fpgalink", "fpgaemu"):
        shutil.copytree(ROOT / "src" / name, src / name,
                        ignore=shutil.ignore_patterns("__pycache__"))
    return src


def _env(src: Path) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(src), PYTHONDONTWRITEBYTECODE="1")


def _compiled_at_import(src: Path) -> list[str]:
    done = subprocess.run([sys.executable, "-c", COUNT_COMPILES], env=_env(src), cwd=src,
                          capture_output=True, text=True, timeout=120, check=True)
    return [p for p in json.loads(done.stdout.splitlines()[-1]) if p.startswith(str(src))]


def _mypyc_group() -> str:
    """The compiled build's group name, as build_support/mypyc_build.py declares it."""
    text = (ROOT / "build_support" / "mypyc_build.py").read_text(encoding="utf-8")
    match = re.search(r'^GROUP = "(\w+)"$', text, re.MULTILINE)
    assert match, "the build names its shared library's group"
    return match.group(1)


def _demo_packages() -> list[str]:
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    match = re.search(r"^BYTECODE_PACKAGES := (.+)$", makefile, re.MULTILINE)
    assert match, "the demo's set-up names the packages it byte-compiles"
    recipe = makefile[makefile.index("$(DEMO_STAMP): "):makefile.index("touch $(DEMO_STAMP)")]
    assert "tools/precompile.py $(BYTECODE_PACKAGES)" in recipe
    assert "--no-compile" in recipe  # the reason the step is needed
    return match.group(1).split()


def test_without_the_step_every_start_compiles_the_package(tmp_path: Path) -> None:
    src = _copy_packages(tmp_path)
    assert len(_compiled_at_import(src)) > 50
    assert len(_compiled_at_import(src)) > 50  # and again: nothing was written


def test_after_the_demos_step_nothing_is_compiled_at_start(tmp_path: Path) -> None:
    src = _copy_packages(tmp_path)
    packages = [p for p in _demo_packages() if p in ("fpgalink", "fpgaemu")]
    assert packages == ["fpgalink", "fpgaemu"]
    check = [sys.executable, str(PRECOMPILE), "--check", *packages]
    assert subprocess.run(check, env=_env(src), capture_output=True, check=False
                          ).returncode == 1
    subprocess.run([sys.executable, str(PRECOMPILE), *packages], env=_env(src), check=True,
                   timeout=120)
    assert subprocess.run(check, env=_env(src), capture_output=True, check=False
                          ).returncode == 0
    assert _compiled_at_import(src) == []


def test_the_demo_compiles_every_package_a_command_imports() -> None:
    """What ``fpgalink-cli param get`` imports outside the standard library is in the
    demo's list (a new dependency of the start-up path would otherwise compile each time)."""
    code = ("import sys, runpy\nsys.argv = ['fpgalink-cli', 'param', 'get', 'TsTimerPeriod']\n"
            "try:\n    runpy.run_module('fpgalink', run_name='__main__')\n"
            "except SystemExit:\n    pass\n"
            "print(' '.join(sorted({m.split('.')[0] for m in sys.modules})), file=sys.stderr)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, timeout=60, check=False,
                          env=dict(os.environ, PYTHONPATH=f"{ROOT / 'src'}:{ROOT}"))
    imported = set(done.stderr.strip().splitlines()[-1].split())
    # What this interpreter loads before any code (site's .pth hooks of other extras).
    bare = subprocess.run([sys.executable, "-c", "import sys; print(' '.join(sys.modules))"],
                          capture_output=True, text=True, timeout=60, check=True)
    imported -= {m.split(".")[0] for m in bare.stdout.split()}
    # The compiled build's one shared library (``fpgalink__mypyc``, beside the packages) is
    # machine code, no bytecode to compile.
    compiled_library = f"{_mypyc_group()}__mypyc"
    third_party = {m for m in imported - set(sys.stdlib_module_names)
                   if not m.startswith("_") and m not in ("tests", compiled_library)}
    missing = third_party - set(_demo_packages())
    assert not missing, f"imported at start-up, not byte-compiled by make demo: {missing}"
