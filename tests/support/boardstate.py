"""Everything a board holds, as one flat ``{path: value}`` dict: every register, counter,
RAM byte, float, pending event and queued wire byte of every block and peripheral, walked
from the :class:`~fpgaemu.board.Board` through attributes, containers and slots (never
through properties, which may change what they read). Two boards that should be in the same
state compare equal here, or the first differing path says where they part. The walk is the
same on both builds: an object's attributes are found in its ``__dict__``, its slots, or
(compiled by mypyc) its class's ``__mypyc_attrs__``, and walked in name order, so a state
from the compiled build compares with one from pure Python."""

from __future__ import annotations

import math
import re
from collections import deque
from enum import Enum
from typing import Any

#: Attributes that are not the board's state (none at present).
IGNORED: frozenset[str] = frozenset()


def board_state(root: object, ignored: frozenset[str] = IGNORED) -> dict[str, object]:
    out: dict[str, object] = {}
    seen: dict[int, str] = {}

    def walk(value: object, path: str) -> None:
        if value is None or isinstance(value, bool | int | str | bytes | Enum):
            out[path] = value
        elif isinstance(value, float):
            out[path] = "nan" if math.isnan(value) else value.hex()
        elif isinstance(value, complex):
            out[path] = (value.real.hex(), value.imag.hex())
        elif isinstance(value, bytearray | memoryview):
            out[path] = bytes(value)
        elif isinstance(value, re.Pattern):
            out[path] = value.pattern
        elif callable(value) and not hasattr(value, "__slots__") and (
                hasattr(value, "__func__") or hasattr(value, "__code__")
                or type(value).__name__ == "builtin_function_or_method"):
            func = getattr(value, "__func__", value)
            out[path] = getattr(func, "__qualname__", repr(type(value)))
        elif type(value).__module__ == "numpy.random._generator":
            out[path] = repr(value.bit_generator.state)  # type: ignore[attr-defined]
        elif isinstance(value, list | tuple | deque):
            out[path + ".len"] = len(value)
            for index, item in enumerate(value):
                walk(item, f"{path}[{index}]")
        elif isinstance(value, set | frozenset):
            out[path] = sorted(repr(item) for item in value)
        elif isinstance(value, dict):
            out[path + ".keys"] = [repr(key) for key in value]
            for key, item in value.items():
                walk(item, f"{path}[{key!r}]")
        else:
            first = seen.get(id(value))
            if first is not None:
                out[path] = f"<same as {first}>"
                return
            seen[id(value)] = path
            out[path + ".type"] = type(value).__qualname__
            for name in _attributes(value):
                if name in ignored:
                    continue
                walk(getattr(value, name), f"{path}.{name}")

    walk(root, "board")
    return out


def _attributes(value: object) -> list[str]:
    names: set[str] = set(getattr(value, "__dict__", {}))
    for klass in type(value).__mro__:
        for name in (*getattr(klass, "__slots__", ()), *getattr(klass, "__mypyc_attrs__", ())):
            if name not in ("__weakref__", "__dict__") and hasattr(value, name):
                names.add(name)
    return sorted(names)


def first_difference(a: dict[str, object], b: dict[str, object]) -> str | None:
    """The first path (in walking order) whose value differs, with both values."""
    for path in list(a) + [p for p in b if p not in a]:
        if a.get(path, "<absent>") != b.get(path, "<absent>"):
            return f"{path}: {a.get(path, '<absent>')!r} != {b.get(path, '<absent>')!r}"
    return None


def same_state(a: Any, b: Any) -> None:
    """Assert two boards are in the same state, naming the first difference."""
    difference = first_difference(board_state(a), board_state(b))
    assert difference is None, difference
