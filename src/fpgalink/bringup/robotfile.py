"""Writing what bring-up found into the files the robot loads: a robot file's
``[surfaces]`` χ and ``wheel_radius`` (calibrate), its ``[board_parameters.NAME.A]`` gains,
or a parameter set's ``[A]``/``[B]`` (autotune).

The user's file is edited, not rewritten: each key's line is found in its table and its
value replaced (a comment after it kept), a missing key goes at the end of its table, a
missing table at the end of the file. The result is parsed again before anything is
written, and must hold the new values — a file the edit cannot be made in (a table written
inline, say) is refused with a clear error, never saved half-right. Sans-I/O: text in,
text out."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping

from fpgalink.protocol.tomlfile import TomlFileError, parse_toml

__all__ = ["EditError", "format_number", "set_values"]

_HEADER = re.compile(r"^\s*\[\s*([A-Za-z0-9_.\- ]+?)\s*\]\s*(#.*)?$")
_ARRAY_HEADER = re.compile(r"^\s*\[\[")


class EditError(ValueError):
    """The file cannot take the edit (the message names the file and the key)."""


def format_number(value: float) -> str:
    """A TOML float with 7 significant digits (a float32 parameter holds about that)."""
    if not math.isfinite(value):
        raise EditError(f"{value!r} is not a finite number")
    text = f"{value:.7g}"
    return text if any(c in text for c in ".en") else text + ".0"


def _key_line(key: str) -> re.Pattern[str]:
    return re.compile(rf"^(\s*{re.escape(key)}\s*=\s*)([^#\n]*?)(\s*#.*)?$")


def _region(lines: list[str], table: str) -> tuple[int, int] | None:
    """(first line after the table's header, the next header's line) of ``table``; the top
    level for ``""``. ``None`` when the table has no header."""
    start = 0 if table == "" else None
    for i, line in enumerate(lines):
        header = _HEADER.match(line)
        if header is None and not _ARRAY_HEADER.match(line):
            continue
        name = ".".join(part.strip() for part in header.group(1).split(".")) if header else ""
        if start is not None:
            return start, i
        if header is not None and name == table:
            start = i + 1
    return None if start is None else (start, len(lines))


def set_values(text: str, values: Mapping[tuple[str, str], float], source: str) -> str:
    """``text`` with each ``(table, key)`` set to its value (table ``""``: the top level;
    dotted for a sub-table: ``"board_parameters.L.A"``)."""
    lines = text.splitlines()
    for (table, key), value in values.items():
        literal = format_number(value)
        region = _region(lines, table)
        if region is None:
            while lines and not lines[-1].strip():
                lines.pop()
            lines += ["", f"[{table}]", f"{key} = {literal}"]
            continue
        start, end = region
        pattern = _key_line(key)
        for i in range(start, end):
            match = pattern.match(lines[i])
            if match is not None:
                lines[i] = f"{match.group(1)}{literal}{match.group(3) or ''}"
                break
        else:
            at = end
            while at > start and not lines[at - 1].strip():
                at -= 1
            lines.insert(at, f"{key} = {literal}")
    result = "\n".join(lines) + "\n"
    _check(result, values, source)
    return result


def _check(text: str, values: Mapping[tuple[str, str], float], source: str) -> None:
    try:
        document = parse_toml(text, source)
    except TomlFileError as exc:
        raise EditError(f"{source}: the edited file would not be TOML ({exc}); edit it by "
                        "hand") from None
    for (table, key), value in values.items():
        node: object = document
        for part in [p for p in table.split(".") if p]:
            node = node.get(part) if isinstance(node, dict) else None
        found = node.get(key) if isinstance(node, dict) else None
        if not isinstance(found, int | float) or not math.isclose(float(found), value,
                                                                  rel_tol=1e-6):
            where = f"[{table}] {key}" if table else key
            raise EditError(f"{source}: {where} could not be set (is the table written "
                            "inline or as a dotted key?); edit it by hand")
