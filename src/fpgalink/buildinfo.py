"""Which build runs: compiled (mypyc) or pure Python, decided once, before any module of
``fpgalink`` or ``fpgaemu`` that may be compiled is loaded (``fpgalink/__init__.py`` imports
this first, and ``fpgaemu/__init__.py`` imports ``fpgalink.protocol`` before anything).

The compiled build puts each compiled module's extension beside its source, and Python
loads an extension before a source of the same name: a source changed after the build would
be shadowed by its stale extension, silently. So the build writes a manifest, each compiled
module's source hash (``build_support/mypyc_build.py``), and here it is checked against the
sources: if every one is as compiled, the extensions load; if any changed, or the manifest
is missing, or its shared library is not beside the packages (an extension would load
another build's from elsewhere on the path), or ``FPGALINK_PURE`` is set, every module of
both packages loads from its source (the compiled modules call one another in C, so it is
all of them or none), and a stale build is said once on stderr. With no compiled build at
all, nothing here is installed.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import os
import sys
from collections.abc import Sequence
from types import ModuleType

__all__ = ["BUILD", "COMPILED", "PURE_ENV", "build_name"]

#: Set (to anything but ``0`` or empty): run pure Python even where a compiled build is
#: installed (the exactness tests run both builds so).
PURE_ENV = "FPGALINK_PURE"
#: The compiled build's manifest, beside this file.
_MANIFEST = "_compiled.txt"
#: Its shared library, beside the packages.
_LIBRARY = "fpgalink__mypyc"
_PACKAGES = ("fpgalink", "fpgaemu")


class _SourcesFirst(importlib.abc.MetaPathFinder):
    """Loads every module of the two packages from its source, except the compiled ones
    this build vouches for: an extension that is not of this build (stale, or left by an
    older one) is never loaded."""

    def __init__(self, compiled: frozenset[str]) -> None:
        self.compiled = compiled

    def find_spec(self, fullname: str, path: Sequence[str] | None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if path is None or fullname in self.compiled or \
                fullname.partition(".")[0] not in _PACKAGES:
            return None
        name = fullname.rpartition(".")[2]
        for entry in path:
            source = os.path.join(entry, name + ".py")
            if os.path.isfile(source):
                return importlib.util.spec_from_file_location(fullname, source)
        return None  # a package, or not here: the usual finders


def _library_present(root: str) -> bool:
    return any(os.path.exists(os.path.join(root, _LIBRARY + suffix))
               for suffix in importlib.machinery.EXTENSION_SUFFIXES)


def _unchanged(root: str, module: str, digest: str, size: int, mtime_ns: int) -> bool:
    source = os.path.join(root, *module.split(".")) + ".py"
    try:
        stat = os.stat(source)
        if stat.st_size != size:
            return False
        if stat.st_mtime_ns == mtime_ns:
            return True
        import hashlib  # only now: most starts need no hash (and its import costs)

        with open(source, "rb") as file:  # touched, maybe not changed: the hash says
            return hashlib.sha256(file.read()).hexdigest() == digest
    except OSError:
        return False


def _decide() -> tuple[frozenset[str], str | None]:
    """The modules to load compiled (none: pure Python), and a stale build's notice."""
    here = os.path.dirname(os.path.abspath(__file__))
    root = os.path.dirname(here)
    try:
        with open(os.path.join(here, _MANIFEST), encoding="utf-8") as file:
            lines = [line.split() for line in file if line.strip() and line[0] != "#"]
    except OSError:
        lines = []
    if not lines and not _library_present(root):
        return frozenset(), None  # a pure install: nothing to guard against
    if os.environ.get(PURE_ENV, "") not in ("", "0"):
        return frozenset(), None
    if not lines:
        return frozenset(), ("fpgalink: compiled modules without their build's manifest "
                             "(an interrupted build?): running pure Python; `make compile` "
                             "rebuilds them")
    if not _library_present(root):
        # Each extension imports the library by name: it would get another build's from
        # elsewhere on the path (or none), and fail at import.
        return frozenset(), ("fpgalink: compiled modules without their build's shared "
                             f"library ({_LIBRARY} beside the packages): running pure "
                             "Python; `make compile` rebuilds it")
    for module, digest, size, mtime_ns in lines:
        if not _unchanged(root, module, digest, int(size), int(mtime_ns)):
            path = os.path.join(root, *module.split(".")) + ".py"
            return frozenset(), (f"fpgalink: {path} changed since the compiled build: "
                                 "running pure Python; `make compile` rebuilds it")
    return frozenset(line[0] for line in lines), None


def _install() -> frozenset[str]:
    compiled, notice = _decide()
    if notice is not None:
        print(notice, file=sys.stderr, flush=True)
    here = os.path.dirname(os.path.abspath(__file__))
    if compiled or notice is not None or _library_present(os.path.dirname(here)) or \
            os.path.exists(os.path.join(here, _MANIFEST)):  # extensions are here
        sys.meta_path.insert(0, _SourcesFirst(compiled))
    return compiled


#: The modules running compiled in this process (empty: pure Python).
COMPILED = _install()
#: What ``--version`` says of the build.
BUILD = "compiled (mypyc)" if COMPILED else "pure Python"


def build_name() -> str:
    """``compiled (mypyc)`` or ``pure Python``: which build this process runs."""
    return BUILD
