"""Building C for the co-simulation: the system C compiler, a cache, and ``cffi`` (ABI mode:
a plain shared object, no Python headers needed).

A build is keyed by everything that goes into it — the sources' text, the compiler and its
version, the flags — and kept under the cache directory (``$FPGAEMU_CACHE_DIR``, else
``$XDG_CACHE_HOME/fpgaemu``, else ``~/.cache/fpgaemu``), so the first use compiles (about a
second) and later ones load. A build is written beside its final place and renamed into it,
so concurrent processes never see half a library.

The declarations ``cffi`` needs are the headers themselves, run through the compiler's
preprocessor with the standard headers stubbed out (``cffi`` knows ``uint8_t``, ``size_t``
and ``bool``): nothing is declared twice.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fpgalink.protocol.exitcodes import NotInstalled

__all__ = ["CBuildError", "CompilerMissing", "SharedLibrary", "build_shared", "cache_dir",
           "find_compiler", "load"]

#: Freestanding C99 as the firmware is written, every warning an error, and no floating-point
#: contraction: a fused multiply-add rounds differently from the Python model.
C_FLAGS = ("-std=c99", "-O2", "-fPIC", "-Wall", "-Wextra", "-Werror", "-pedantic",
           "-ffp-contract=off", "-fno-fast-math")
_STUB_HEADERS = ("stdint.h", "stddef.h", "stdbool.h")


class CBuildError(ValueError):
    """The C could not be built (a compiler error, a missing compiler, a missing cffi)."""


class CompilerMissing(CBuildError, NotInstalled):
    """No C compiler: ``$CC``, ``cc``, ``gcc`` and ``clang`` were all not found."""


class CffiMissing(CBuildError, NotInstalled):
    """cffi, which loads the built library, is not installed (the ``cosim`` extra)."""


def find_compiler() -> str | None:
    """The C compiler to use, or ``None``."""
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name:
            path = shutil.which(name)
            if path:
                return path
    return None


def cache_dir() -> Path:
    """Where builds are kept: ``$FPGAEMU_CACHE_DIR``, else the user's cache directory, else
    (not writable, or no home) a directory of this user's under the system's temporary
    directory."""
    explicit = os.environ.get("FPGAEMU_CACHE_DIR")
    if explicit:
        return Path(explicit)
    xdg = os.environ.get("XDG_CACHE_HOME")
    try:
        preferred = (Path(xdg) if xdg else Path.home() / ".cache") / "fpgaemu"
        preferred.mkdir(parents=True, exist_ok=True)
        if os.access(preferred, os.W_OK):
            return preferred
    except (OSError, RuntimeError):  # RuntimeError: no home directory to be found
        pass
    return Path(tempfile.gettempdir()) / f"fpgaemu-{os.getuid()}"


@dataclass(frozen=True, slots=True)
class SharedLibrary:
    path: Path  #: the shared object
    cdef: str  #: its declarations, preprocessed, for cffi


def _compiler_identity(cc: str) -> str:
    try:
        done = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=30,
                              check=False)
    except OSError as exc:
        raise CompilerMissing(f"the C compiler {cc} cannot run: {exc}") from None
    return cc + "\n" + done.stdout


def build_shared(name: str, sources: Sequence[Path], headers: Sequence[Path],
                 include_dirs: Sequence[Path]) -> SharedLibrary:
    """``sources`` compiled into one shared object, and ``headers`` preprocessed into its
    declarations; from the cache when an identical build was made before."""
    cc = find_compiler()
    if cc is None:
        raise CompilerMissing("no C compiler found (set CC, or install one: on Debian "
                              "`apt-get install gcc`)")
    digest = hashlib.sha256()
    digest.update(_compiler_identity(cc).encode())
    digest.update(repr(C_FLAGS).encode())
    for path in (*sources, *headers, *(p for d in include_dirs for p in sorted(d.glob("*.h")))):
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    key = f"{name}-{digest.hexdigest()[:20]}"
    final = cache_dir() / key
    library, declarations = final / f"lib{name}.so", final / "cdef.h"
    if library.exists() and declarations.exists():
        return SharedLibrary(library, declarations.read_text(encoding="utf-8"))
    final.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{key}-", dir=final.parent))
    try:
        includes = [f"-I{d}" for d in include_dirs]
        _run([cc, *C_FLAGS, "-shared", *includes, *map(str, sources), "-o",
              str(work / library.name)], "compiling")
        stubs = work / "stubs"
        stubs.mkdir()
        for header in _STUB_HEADERS:
            (stubs / header).write_text("/* stub: cffi knows these types */\n",
                                        encoding="utf-8")
        wrapper = work / "all.h"
        wrapper.write_text("".join(f'#include "{h}"\n' for h in headers), encoding="utf-8")
        cdef = _run([cc, "-E", "-P", "-nostdinc", f"-I{stubs}", *includes, str(wrapper)],
                    "preprocessing")
        (work / "cdef.h").write_text(cdef, encoding="utf-8")
        try:
            work.rename(final)
        except OSError:
            if not (library.exists() and declarations.exists()):  # not another process's win
                raise
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)
    return SharedLibrary(library, declarations.read_text(encoding="utf-8"))


def _run(command: list[str], what: str) -> str:
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, check=False)
    if done.returncode != 0:
        raise CBuildError(f"{what} failed ({' '.join(command[:1])}): "
                          + (done.stderr.strip() or done.stdout.strip())[:2000])
    return done.stdout


def load(shared: SharedLibrary) -> tuple[Any, Any]:
    """``(ffi, lib)`` for the library, through cffi's ABI mode."""
    try:
        import cffi
    except ImportError:
        raise CffiMissing("the C co-simulation needs cffi: pip install 'fpgalink[cosim]'"
                          ) from None
    ffi = cffi.FFI()
    ffi.cdef(shared.cdef)
    return ffi, ffi.dlopen(str(shared.path))
