"""Parameter files: the TOML that ``fpgalink-cli param dump`` writes and ``param load`` and
``fpgaemu serve --config`` read — one format, one parser, on both sides of the cable.

Top level: board parameters, or channel parameters with the seed's suffix
(``Kp_Wheel_PidA``); tables ``[A]`` and ``[B]``: channel parameters without it. Every value is
validated as the host validates a ``PS`` (:meth:`~fpgalink.protocol.params.Param.coerce`),
so a file is all good or refused as a whole, with a one-line error naming the file and key.
"""

from __future__ import annotations

from collections.abc import Mapping

from fpgalink.protocol.errors import ParameterError
from fpgalink.protocol.params import (
    BOARD,
    CHANNEL_A,
    CHANNEL_B,
    PARAMETERS,
    Param,
    ParamType,
    Scope,
    channel_name,
    float32,
    resolve,
)
from fpgalink.protocol.tomlfile import TomlFileError, parse_toml

__all__ = [
    "Setting",
    "format_value",
    "parse_parameter_file",
    "parse_parameter_table",
    "render_parameter_file",
]

#: One parameter address and the value it is to hold, as it will travel.
Setting = tuple[Param, int, int | float]


def parse_parameter_file(text: str, source: str) -> list[Setting]:
    """TOML text → validated settings, in file order; :class:`ParameterError` otherwise
    (text over :data:`~fpgalink.protocol.tomlfile.MAX_TOML_BYTES` included)."""
    try:
        document = parse_toml(text, source)
    except TomlFileError as exc:
        raise ParameterError(str(exc)) from None
    return parse_parameter_table(document, source)


def parse_parameter_table(document: Mapping[str, object], source: str) -> list[Setting]:
    """A parsed TOML table (a whole file, or a section of a larger one) → settings."""
    entries: list[tuple[str, str | None, object]] = []
    for key, value in document.items():
        if isinstance(value, dict):
            if key.upper() not in ("A", "B"):
                raise ParameterError(f"{source}: unknown table [{key}]; use [A] or [B]")
            entries += [(str(name), key.upper(), v) for name, v in value.items()]
        else:
            entries.append((key, None, value))
    settings: list[Setting] = []
    seen: set[tuple[int, int]] = set()
    for name, channel, value in entries:
        where = f"[{channel}] {name}" if channel else name
        try:
            param, code = resolve(name, channel)
        except ParameterError as exc:
            raise ParameterError(f"{source}: {where}: {exc}") from None
        if (param.id, code) in seen:
            raise ParameterError(f"{source}: {param.full_name(code)} given twice")
        seen.add((param.id, code))
        try:
            settings.append((param, code, param.coerce(value)))
        except ParameterError as exc:
            raise ParameterError(f"{source}: {param.full_name(code)}: {exc}") from None
    return settings


def format_value(value: int | float, kind: ParamType | None = None) -> str:
    """A parameter value as the shortest text that means the same stored value: floats are
    float32 on the board, so ``7.11`` prints as ``7.11``, not ``7.110000133514404``."""
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, int) and kind is not ParamType.FLOAT:
        return str(value)
    number = float(value)
    if number != number or number in (float("inf"), float("-inf")):
        return str(number)
    if kind is ParamType.INT and number.is_integer():
        return str(int(number))
    try:
        stored = float32(number)
    except OverflowError:
        return repr(number)
    text = repr(stored)
    for digits in range(1, 10):
        text = f"{stored:.{digits}g}"
        if float32(float(text)) == stored:
            break
    # repr() of the same decimal gives fixed notation where Python would (520.0, not
    # 5.2e+02) and keeps it a float to the eye and to TOML (7 → 7.0).
    return repr(float(text))


def render_parameter_file(values: Mapping[tuple[int, int], int | float], header: str) -> str:
    """Values by ``(param id, channel)`` as TOML: board parameters at the top, then ``[A]``
    and ``[B]``; each line notes the range and unit. ``header`` is the first comment line."""
    lines = [f"# {header}",
             "# NAME = VALUE  # range, unit. Load with: fpgalink-cli param load FILE", ""]

    def line(param: Param, code: int) -> str:
        note = ", ".join(x for x in (param.range_text, param.unit) if x)
        return f"{param.name} = {format_value(values[(param.id, code)], param.type)}  # {note}"

    lines += [line(p, BOARD) for p in PARAMETERS
              if p.scope is Scope.BOARD and (p.id, BOARD) in values]
    for code in (CHANNEL_A, CHANNEL_B):
        lines += ["", f"[{channel_name(code)}]"]
        lines += [line(p, code) for p in PARAMETERS
                  if p.scope is Scope.CHANNEL and (p.id, code) in values]
    return "\n".join(lines) + "\n"
