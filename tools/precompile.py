"""Byte-compile the packages a command imports, once, at install (``make demo``).

``make demo`` installs with ``--no-compile`` (45 MB less), so bytecode is written as modules
are first imported; where ``PYTHONDONTWRITEBYTECODE=1`` is set (common in containers) it is
never written, and every ``fpgalink-cli param get`` compiled the package again (1.35–2.2 s
against 0.6–0.9 s with bytecode). This compiles the packages named — fpgalink, fpgaemu and
the main job's dependencies, a few MB, not matplotlib's 40 — whatever that variable says.

    python tools/precompile.py fpgalink fpgaemu click rich …     # compile
    python tools/precompile.py --check fpgalink fpgaemu          # exit 1 if any is stale
"""

from __future__ import annotations

import argparse
import compileall
import importlib.util
import re
import sys
from pathlib import Path

#: Parts of the packages no command imports (numpy's own tests, build tools: most of its
#: size), left to be compiled if ever imported.
NOT_IMPORTED = re.compile(r"[/\\](tests?|testing|f2py|_pyinstaller|distutils|typing)[/\\]")


def package_dir(name: str) -> Path:
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit(f"precompile: {name} is not an installed package")
    return Path(next(iter(spec.submodule_search_locations)))


def stale(folder: Path) -> list[Path]:
    """The modules under ``folder`` whose bytecode is missing or older than the source."""
    found = []
    for source in sorted(folder.rglob("*.py")):
        if NOT_IMPORTED.search(str(source)):
            continue
        cached = Path(importlib.util.cache_from_source(str(source)))
        if not cached.exists() or cached.stat().st_mtime < source.stat().st_mtime:
            found.append(source)
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true",
                        help="compile nothing; exit 1 naming the modules without bytecode")
    parser.add_argument("packages", nargs="+")
    args = parser.parse_args()
    folders = [package_dir(name) for name in args.packages]
    if args.check:
        missing = [path for folder in folders for path in stale(folder)]
        for path in missing:
            print(f"precompile: no bytecode for {path}", file=sys.stderr)
        sys.exit(1 if missing else 0)
    ok = all(compileall.compile_dir(folder, quiet=1, workers=0, rx=NOT_IMPORTED)
             for folder in folders)
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
