"""Reading the TOML files a user names — a robot description, ``fpgalink.toml``, a parameter
file for ``param load`` or ``fpgaemu serve --config`` — bounded and safe, for both sides of
the cable: every TOML read in the project comes through here.

A file is read up to :data:`MAX_TOML_BYTES` and refused beyond it (``/dev/zero`` given as a
config would otherwise be read until memory runs out); what ``tomllib`` cannot take — bad
syntax, nesting deep enough to exhaust the interpreter's stack — becomes one
:class:`TomlFileError` line naming the file, never a traceback.
"""

from __future__ import annotations

import tomllib
from typing import IO, Any

from fpgalink.protocol.errors import FpgalinkError

__all__ = ["MAX_TOML_BYTES", "TomlFileError", "load_toml", "parse_toml", "read_bounded"]

#: The largest TOML file read: the seed's robot file is 2 KiB, a full parameter dump 1 KiB.
MAX_TOML_BYTES = 1 << 20


class TomlFileError(FpgalinkError, ValueError):
    """A TOML file that cannot be read or parsed; the message is one line naming it."""


def read_bounded(stream: IO[bytes], source: str, limit: int = MAX_TOML_BYTES) -> str:
    """At most ``limit`` bytes of ``stream`` as UTF-8 text; :class:`TomlFileError` if there
    is more (nothing beyond ``limit + 1`` bytes is read) or it is not UTF-8."""
    data = stream.read(limit + 1)
    if len(data) > limit:
        raise TomlFileError(f"{source}: larger than {_size(limit)}; refused (a robot or "
                            "settings file is a few KiB)")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise TomlFileError(f"{source}: not UTF-8 text (byte {exc.start})") from None


def parse_toml(text: str, source: str, limit: int = MAX_TOML_BYTES) -> dict[str, Any]:
    """TOML text → its table; :class:`TomlFileError` naming ``source`` for text over
    ``limit`` bytes, bad syntax or nesting too deep to parse."""
    if len(text) > limit or len(text.encode("utf-8", "surrogatepass")) > limit:
        raise TomlFileError(f"{source}: larger than {_size(limit)}; refused (a robot or "
                            "settings file is a few KiB)")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise TomlFileError(f"{source}: not valid TOML: {exc}") from None
    except RecursionError:
        raise TomlFileError(f"{source}: arrays or tables nested too deeply to read") from None


def load_toml(path: str, source: str | None = None) -> dict[str, Any]:
    """The TOML file at ``path``, read with :func:`read_bounded` and parsed with
    :func:`parse_toml`; errors name ``source`` (default: the path)."""
    where = source or path
    try:
        with open(path, "rb") as stream:
            text = read_bounded(stream, where)
    except OSError as exc:
        raise TomlFileError(f"{where}: cannot read: {exc.strerror or exc}") from None
    return parse_toml(text, where)


def _size(limit: int) -> str:
    return f"{limit // (1 << 20)} MiB" if limit % (1 << 20) == 0 else f"{limit:,} bytes"
