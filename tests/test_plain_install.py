"""A plain ``pip install fpgalink`` (no extra) gives a working CLI and emulator (issue 26).

The test environment has every extra installed, so a child interpreter is given only what a
plain install would have: the standard library, fpgalink and fpgaemu, and the distributions
the package requires without an extra (and what they require in turn). Any other import
fails there as it would on a plain install. The declared requirements are checked too, so
a heavy dependency cannot slip into the plain install unnoticed."""

from __future__ import annotations

import re
import subprocess
import sys
from importlib import metadata

import pytest

from tests.support.cli import ROOT, cli_env
from tests.support.serving import served

pytestmark = pytest.mark.timeout(120)

#: What a plain install may pull in: the light main job (issue 26, "under 200 MB").
CORE = {"pyserial", "numpy", "construct", "click", "rich", "mcap"}


def _name(requirement: str) -> str:
    return re.split(r"[\s;\[<>=!~(]", requirement, maxsplit=1)[0].lower().replace("_", "-")


def _plain_requirements(dist: str) -> list[str]:
    return [r for r in metadata.requires(dist) or [] if "extra ==" not in r]


def _closure() -> set[str]:
    """The distributions a plain install brings: the core and, transitively, theirs."""
    seen: set[str] = set()
    todo = [_name(r) for r in _plain_requirements("fpgalink")]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        try:
            requirements = _plain_requirements(name)
        except metadata.PackageNotFoundError:
            continue
        for requirement in requirements:
            marker = requirement.split(";", 1)[1] if ";" in requirement else ""
            if "python_version <" in marker or "sys_platform == \"win32\"" in marker:
                continue
            todo.append(_name(requirement))
    return seen


def test_a_plain_install_requires_only_the_light_core() -> None:
    assert {_name(r) for r in _plain_requirements("fpgalink")} == CORE


# fpgalink__mypyc: the compiled build's shared library, beside the packages (docs/emulator.md,
# "The compiled build").
GUARD = """
import importlib.abc, sys
ALLOWED = set({allowed!r}) | set(sys.stdlib_module_names) | {{"fpgalink", "fpgaemu", "tests",
                                                             "fpgalink__mypyc"}}
class Plain(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] not in ALLOWED:
            raise ModuleNotFoundError(f"No module named {{name!r}} (not in a plain install)")
        return None
sys.meta_path.insert(0, Plain())
sys.argv = [{prog!r}] + {args!r}
"""


def _guarded(prog: str, entry: str, *args: str) -> str:
    """Python code running ``entry`` as ``prog ARGS`` with only a plain install's imports."""
    modules: set[str] = set()
    closure = _closure()
    for module, dists in metadata.packages_distributions().items():
        if any(d.lower().replace("_", "-") in closure for d in dists):
            modules.add(module)
    return GUARD.format(allowed=sorted(modules), prog=prog, args=list(args)) + entry


def _plain(prog: str, entry: str, *args: str, timeout: float = 90
           ) -> subprocess.CompletedProcess[str]:
    code = _guarded(prog, entry, *args)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, env=cli_env(), timeout=timeout)


CLI = "from fpgalink.cli import main\nmain()\n"
EMU = "from fpgaemu.__main__ import main\nmain()\n"


def test_the_guard_refuses_an_extra() -> None:
    done = _plain("fpgalink-cli", "import matplotlib\n")
    assert done.returncode != 0 and "not in a plain install" in done.stderr


def test_the_cli_works_on_a_plain_install() -> None:
    done = _plain("fpgalink-cli", CLI, "param", "list", "--format", "json")
    assert done.returncode == 0, done.stderr
    assert "TsTimerPeriod" in done.stdout
    done = _plain("fpgalink-cli", CLI, "step", "--channel", "A", "--to", "45", "--pre", "0.1",
                  "--hold", "0.5")
    assert done.returncode == 0, done.stderr
    assert "rise time" in done.stdout
    # What needs an extra says which one, in one line.
    done = _plain("fpgalink-cli", CLI, "step", "--channel", "A", "--to", "45", "--plot",
                  "x.png")
    assert done.returncode != 0 and "fpgalink[plot]" in done.stderr
    assert "Traceback" not in done.stderr


def test_the_emulator_works_on_a_plain_install() -> None:
    done = _plain("fpgaemu", EMU, "--help")
    assert done.returncode == 0, done.stderr
    # fpgaemu serve on a pty, and the CLI reading the served board's parameters.
    # The guard sets serve's command line itself: the helper's is ignored.
    code = _guarded("fpgaemu", EMU, "serve", "--pty")
    with served(command=(sys.executable, "-c", code), cwd=ROOT, env=cli_env()) as serve:
        done = _plain("fpgalink-cli", CLI, "param", "get", "TsTimerPeriod", "--port",
                      serve.url)
        assert done.returncode == 0, done.stderr
        assert done.stdout == "1\n"
