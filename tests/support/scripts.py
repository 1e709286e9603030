"""The console scripts as a user runs them (``fpgalink-cli``, ``fpgaemu``, ``fpgalink-ros2``
from the environment's ``bin``), importing this checkout's packages."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from tests.support.cli import CALL_TIMEOUT, ROOT, cli_env

__all__ = ["BIN", "script", "script_env", "start_script", "without"]

#: Where the environment's console scripts are (the interpreter's own ``bin``).
BIN = Path(sys.executable).parent


def script_env(**extra: str) -> dict[str, str]:
    """The CLI tests' environment, with this checkout first on the path so an installed
    console script runs this code."""
    env = cli_env(**extra)
    env["PYTHONPATH"] = os.pathsep.join(
        [str(ROOT / "src"), str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def script(name: str, *args: str, env: dict[str, str] | None = None,
           timeout: float = CALL_TIMEOUT, **options: Any) -> subprocess.CompletedProcess[str]:
    """Run console script ``name`` to its end."""
    return subprocess.run([str(BIN / name), *args], capture_output=True, text=True,
                          cwd=options.pop("cwd", ROOT), env=env or script_env(),
                          timeout=timeout, **options)


def start_script(name: str, *args: str, env: dict[str, str] | None = None,
                 **options: Any) -> subprocess.Popen[str]:
    """Start console script ``name``; stdout and stderr are pipes unless given."""
    options.setdefault("stdout", subprocess.PIPE)
    options.setdefault("stderr", subprocess.PIPE)
    return subprocess.Popen([str(BIN / name), *args], text=True,
                            cwd=options.pop("cwd", ROOT), env=env or script_env(), **options)


def without(tmp_path: Path, *modules: str) -> dict[str, str]:
    """:func:`script_env` in which each of ``modules`` fails to import, as where the extra
    that brings it is not installed (a package of that name raising ImportError, first on
    the path)."""
    for name in modules:
        (tmp_path / name).mkdir(exist_ok=True)
        (tmp_path / name / "__init__.py").write_text(
            f"raise ImportError('No module named {name} (hidden by the test)')\n",
            encoding="utf-8")
    env = script_env()
    env["PYTHONPATH"] = f"{tmp_path}{os.pathsep}{env['PYTHONPATH']}"
    return env
