"""How a package of fpgalink exports names from its submodules: each imported on first use
(PEP 562), so importing one part (the wire arithmetic, the CLI's ``--help``) does not
import the rest (construct, asyncio). It lives in the protocol package because every other
one may import that.

A package maps each public name to its home, imports the same names under ``if
TYPE_CHECKING:`` for the type checkers, and lists them in ``__all__``
(``tests/test_layering.py`` checks the three agree)::

    _HOMES = {"byte_time_s": "fpgalink.protocol.wire"}
    __getattr__ = lazy_exports(__name__, _HOMES)
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(package: str, homes: Mapping[str, str]) -> Callable[[str], Any]:
    """``package``'s module ``__getattr__``: a name in ``homes`` (name → the module that
    defines it) is imported from there the first time it is asked for, and kept in the
    package."""
    module = sys.modules[package]

    def __getattr__(name: str) -> Any:
        home = homes.get(name)
        if home is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(home), name)
        setattr(module, name, value)
        return value

    return __getattr__
