"""The wheel's build hook: the compiled build (mypyc) where it can be made, pure Python where
it cannot, from the same source. ``build_support/mypyc_build.py`` holds the list of compiled
modules and the build itself; this hook only asks for its tools and packs what it made.

* ``FPGALINK_PURE=1`` at build time: pure Python, and mypy is not even fetched;
* no C compiler or no Python headers: pure Python, said in one line;
* a wheel: the extensions and the manifest packed beside the sources, tagged for this
  interpreter and platform;
* an editable install (``pip install -e``, ``make setup``): compiled in place, beside the
  sources in ``src/``, where the editable install finds them.
"""

from __future__ import annotations

import importlib.util
import shutil
import sys
import tempfile
from pathlib import Path
from types import ModuleType
from typing import Any

from hatchling.builders.hooks.plugin.interface import BuildHookInterface

#: mypyc's version the build is made and tested with (mypy ships mypyc).
MYPYC = "mypy==2.4.1"


def _builder(root: str) -> ModuleType:
    path = Path(root) / "build_support" / "mypyc_build.py"
    spec = importlib.util.spec_from_file_location("fpgalink_mypyc_build", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class CompiledBuildHook(BuildHookInterface):  # type: ignore[misc]
    PLUGIN_NAME = "custom"
    #: where a wheel's compiled files wait until the wheel is written
    scratch: str | None = None

    def dependencies(self) -> list[str]:
        if _builder(self.root).pure_requested():
            return []
        return [MYPYC, "setuptools>=69"]

    def initialize(self, version: str, build_data: dict[str, Any]) -> None:
        builder = _builder(self.root)
        root = Path(self.root)
        if builder.pure_requested():
            print(f"fpgalink: {builder.PURE_ENV} is set: pure Python", file=sys.stderr)
            if version == "editable":
                builder.remove_compiled(root / "src")
            return
        try:
            if version == "editable":
                builder.compile_in_place(root)
                return
            self.scratch = tempfile.mkdtemp(prefix="fpgalink-wheel-")
            out = Path(self.scratch) / "out"
            made = builder.build(root, Path(self.scratch) / "work", out)
        except builder.BuildUnavailable as exc:
            print(f"fpgalink: no compiled build ({exc}): pure Python", file=sys.stderr)
            return
        for relative in made:
            build_data["force_include"][str(out / relative)] = str(relative)
        build_data["pure_python"] = False
        build_data["infer_tag"] = True

    def finalize(self, version: str, build_data: dict[str, Any], artifact_path: str) -> None:
        if self.scratch is not None:
            shutil.rmtree(self.scratch, ignore_errors=True)
            self.scratch = None
