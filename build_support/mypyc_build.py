"""The compiled build: mypyc over the modules that do the emulator's per-millisecond work and
the protocol's codec, from the same typed source as the pure-Python build (docs/emulator.md,
"The compiled build").

:data:`COMPILED` is the one list of compiled modules. The wheel's build hook
(``hatch_build.py``) calls :func:`build` and packs what it made; ``make compile`` runs this
file, which builds in place (the extension modules beside their sources in ``src/``, what an
editable install and ``PYTHONPATH=src`` see). Every build writes a manifest, the source hash
of each compiled module (:data:`MANIFEST`); at import ``fpgalink.buildinfo`` refuses a build
whose sources have changed since, and runs pure Python (saying so), so a changed ``.py`` is
never shadowed by a stale extension.

Nothing here is imported by the packages: mypyc and setuptools are build-time tools only.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import sys
import sysconfig
import tempfile
import time
from pathlib import Path
from typing import Any

#: The modules compiled: what runs every emulated millisecond (the board's blocks, its
#: firmware, the wheels, the robot's lockstep), the protocol's counters, codec, framing and
#: wire CRC, and the host's per-message work: the sans-I/O connection's parts and counts,
#: the boards' clock, and the robot's per-sample modules (odometry, tracking, stamping,
#: joints). Not serving/ (the event loop's code, which waits on I/O), __main__, the C
#: co-simulation, the faults' parser or the physics body (MuJoCo's stepping is numpy
#: calls); not the protocol's events and the modules declaring them (catalogue,
#: framingerrors, messages, event, events.py: frozen dataclasses, which a compiled class
#: cannot derive from and whose constructors mypyc leaves to Python; docs/emulator.md says
#: more), nor the asyncio layer.
COMPILED = (
    "fpgaemu.timeline",
    "fpgaemu.bram",
    "fpgaemu.uart",
    "fpgaemu.uartcommand",
    "fpgaemu.uartsend",
    "fpgaemu.axi",
    "fpgaemu.pwm",
    "fpgaemu.encoder",
    "fpgaemu.timer",
    "fpgaemu.pid",
    "fpgaemu.timing",
    "fpgaemu.hwcontrol",
    "fpgaemu.motor",
    "fpgaemu.board",
    "fpgaemu.firmware",
    "fpgaemu.body",
    "fpgaemu.robot",
    "fpgalink.protocol.counter",
    "fpgalink.protocol.codec",
    "fpgalink.protocol.framing",
    "fpgalink.protocol.crc",
    "fpgalink.connection.stats",
    "fpgalink.connection.queue",
    "fpgalink.connection.counting",
    "fpgalink.connection.frames",
    "fpgalink.connection.liveness",
    "fpgalink.connection.pacing",
    "fpgalink.connection.requests",
    "fpgalink.connection.restart",
    "fpgalink.connection.core",
    "fpgalink.boardclock",
    "fpgalink.robot.odometry",
    "fpgalink.robot.tracking",
    "fpgalink.robot.stamping",
    "fpgalink.robot.joints",
)
#: The shared library every compiled module's extension loads (mypyc names it
#: ``GROUP__mypyc``): one library, so calls between the modules are C calls.
GROUP = "fpgalink"
#: Where the build's manifest goes, relative to the directory holding the packages.
MANIFEST = Path("fpgalink") / "_compiled.txt"
#: Set (to anything but ``0`` or empty) at build time: no compiled build, pure Python only.
#: At run time: the compiled modules are not loaded (``fpgalink.buildinfo``).
PURE_ENV = "FPGALINK_PURE"
#: The C compiler's optimisation (docs/emulator.md, "The compiled build", has what each
#: level costs to build and to run).
OPT_LEVEL = "2"

__all__ = ["COMPILED", "GROUP", "MANIFEST", "PURE_ENV", "build", "compile_in_place",
           "missing_tools", "pure_requested", "remove_compiled"]


def _parallel_build_ext() -> type:
    """setuptools' ``build_ext`` compiling an extension's C files in parallel, one per core
    (it compiles them one after another): the compiled build is one extension of many C
    files, one per module (mypyc's ``multi_file``)."""
    from concurrent.futures import ThreadPoolExecutor

    from setuptools.command.build_ext import build_ext

    class ParallelBuildExt(build_ext):  # type: ignore[misc]
        def build_extensions(self) -> None:
            compiler = self.compiler
            serial = compiler._compile

            def compile_all(sources: list[str], output_dir: str | None = None,
                            macros: Any = None, include_dirs: Any = None, debug: bool = False,
                            extra_preargs: Any = None, extra_postargs: Any = None,
                            depends: Any = None) -> list[str]:
                macros, objects, extra_postargs, pp_opts, build = compiler._setup_compile(
                    output_dir, macros, include_dirs, sources, depends, extra_postargs)
                cc_args = compiler._get_cc_args(pp_opts, debug, extra_preargs)

                def one(obj: str) -> None:
                    src, ext = build[obj]
                    serial(obj, src, ext, cc_args, extra_postargs, pp_opts)

                with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
                    list(pool.map(one, objects))
                return list(objects)

            compiler.compile = compile_all
            super().build_extensions()

    return ParallelBuildExt


class BuildUnavailable(Exception):
    """The compiled build cannot be made here (no compiler, no headers, mypyc failed)."""


def pure_requested() -> bool:
    return os.environ.get(PURE_ENV, "") not in ("", "0")


def missing_tools() -> str | None:
    """Why a C extension cannot be built here, or ``None``."""
    compiler = (os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc").split()[0]
    if shutil.which(compiler) is None:
        return f"no C compiler ({compiler} not found)"
    headers = Path(sysconfig.get_paths()["include"]) / "Python.h"
    if not headers.exists():
        return f"no Python headers ({headers} missing: install python3-dev)"
    return None


def _source(src: Path, module: str) -> Path:
    return src.joinpath(*module.split(".")).with_suffix(".py")


def manifest_text(src: Path) -> str:
    """The manifest for the sources in ``src`` now: each compiled module's source hash,
    size and modification time (the size and time let a check skip the hash when they
    match)."""
    lines = [f"# fpgalink compiled build: mypyc; library {GROUP}__mypyc; "
             "module sha256 size mtime_ns"]
    for module in COMPILED:
        path = _source(src, module)
        stat = path.stat()
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        lines.append(f"{module} {digest} {stat.st_size} {stat.st_mtime_ns}")
    return "\n".join(lines) + "\n"


def build(root: Path, work: Path, out: Path, *, quiet: bool = False) -> list[Path]:
    """Compile :data:`COMPILED` from ``root/src`` into ``out`` (package layout: the group's
    library at its top, each module's extension in its package, the manifest); C sources
    and objects in ``work``. Returns the files made, relative to ``out``.
    :class:`BuildUnavailable` when the build cannot be made."""
    missing = missing_tools()
    if missing is not None:
        raise BuildUnavailable(missing)
    src = root / "src"
    manifest = manifest_text(src)  # of the sources as they are when compiling starts
    try:
        import setuptools  # noqa: F401  (mypyc builds through setuptools when it is there)
        from mypyc.build import mypycify
        from setuptools import Distribution
    except ImportError as exc:
        raise BuildUnavailable(f"mypyc or setuptools missing ({exc})") from None
    work.mkdir(parents=True, exist_ok=True)
    lib = work / "lib"
    paths = [str(_source(src, module)) for module in COMPILED]
    options = [
        f"--config-file={root / 'pyproject.toml'}",
        f"--cache-dir={work / 'mypy_cache'}",
        # The build environment may lack the runtime's libraries (numpy) and the extras
        # (MuJoCo): what the compiled modules use of them is untyped objects either way.
        "--ignore-missing-imports",
        "--no-warn-unused-ignores",
        "--follow-imports=silent",
    ]
    cwd = Path.cwd()
    cflags = os.environ.get("CFLAGS")
    started = time.monotonic()
    try:
        os.chdir(root)  # mypyc names the modules from their paths relative to here
        # No fused multiply-add: the compiled float arithmetic must round as Python's does,
        # bit for bit (where the platform has FMA, a compiler may otherwise fuse a*b + c).
        if sys.platform != "win32":  # gcc's and clang's flag (MSVC does not contract)
            os.environ["CFLAGS"] = f"{cflags or ''} -ffp-contract=off".strip()
        extensions = mypycify([*paths, *options], opt_level=OPT_LEVEL, debug_level="0",
                              group_name=GROUP, target_dir=str(work / "c"),
                              multi_file=True)
        dist = Distribution({"name": "fpgalink-compiled", "ext_modules": extensions,
                             "package_dir": {"": "src"},
                             "cmdclass": {"build_ext": _parallel_build_ext()}})
        dist.verbose = 0 if quiet else 1
        command = dist.get_command_obj("build_ext")
        command.build_lib = str(lib)
        command.build_temp = str(work / "obj")
        command.parallel = os.cpu_count() or 1
        dist.run_command("build_ext")
    except SystemExit as exc:  # mypyc says what failed and exits
        raise BuildUnavailable(f"mypyc failed: {exc}") from None
    except Exception as exc:  # the compiler's errors, whatever setuptools calls them
        raise BuildUnavailable(f"compiling failed: {exc}") from None
    finally:
        os.chdir(cwd)
        if cflags is None:
            os.environ.pop("CFLAGS", None)
        else:
            os.environ["CFLAGS"] = cflags
    made = sorted(Path(p).relative_to(lib) for p in command.get_outputs())
    out.mkdir(parents=True, exist_ok=True)
    for relative in made:
        target = out / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(lib / relative, target)
    (out / MANIFEST).parent.mkdir(parents=True, exist_ok=True)
    (out / MANIFEST).write_text(manifest, encoding="utf-8")
    if not quiet:
        print(f"fpgalink: compiled {len(COMPILED)} modules with mypyc in "
              f"{time.monotonic() - started:.0f} s", file=sys.stderr)
    return [*made, MANIFEST]


def remove_compiled(src: Path) -> list[Path]:
    """Every compiled file in ``src`` (a previous in-place build's), the manifest first, so
    an interrupted removal leaves no manifest vouching for what is left."""
    removed = []
    manifest = src / MANIFEST
    if manifest.exists():
        manifest.unlink()
        removed.append(manifest)
    suffixes = tuple(s for s in (".so", ".pyd") if s)
    for package in ("fpgalink", "fpgaemu"):
        for path in (src / package).rglob("*"):
            if path.suffix in suffixes and path.is_file():
                path.unlink()
                removed.append(path)
    for path in src.glob(f"{GROUP}__mypyc*"):
        path.unlink()
        removed.append(path)
    return removed


def compile_in_place(root: Path, work: Path | None = None) -> None:
    """The developer's build (``make compile``, an editable install): compiled into
    ``root/src``, beside the sources. What an earlier build left is removed first; a build
    that fails leaves none."""
    src = root / "src"
    remove_compiled(src)
    if pure_requested():
        print(f"fpgalink: {PURE_ENV} is set: pure Python, nothing compiled", file=sys.stderr)
        return
    with tempfile.TemporaryDirectory(prefix="fpgalink-build-") as scratch:
        out = Path(scratch) / "out"
        build(root, work or root / "build" / "mypyc", out)
        # Everything but the manifest first: until it is there, nothing is loaded.
        files = sorted(p for p in out.rglob("*") if p.is_file())
        for path in sorted(files, key=lambda p: p.relative_to(out) == MANIFEST):
            target = src / path.relative_to(out)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, target)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clean", action="store_true",
                        help="remove the in-place compiled modules (pure Python from then)")
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1])
    args = parser.parse_args(argv)
    if args.clean:
        removed = remove_compiled(args.root / "src")
        print(f"fpgalink: removed {len(removed)} compiled file(s)", file=sys.stderr)
        return 0
    try:
        compile_in_place(args.root)
    except BuildUnavailable as exc:
        print(f"fpgalink: no compiled build ({exc}): pure Python", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
