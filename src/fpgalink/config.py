"""The config file ``fpgalink.toml`` and port lists (``NAME=URL``), read the same way by every
front end: the CLI (:mod:`fpgalink.cli.settings`, which adds the command line and the
environment on top) and the ROS 2 node. Errors are :class:`ConfigError`, one line each.

The file is ``fpgalink.toml`` in the working directory, else
``$XDG_CONFIG_HOME/fpgalink/fpgalink.toml`` (``~/.config/fpgalink/fpgalink.toml``); an
explicit name (``--config FILE``, ``FPGALINK_CONFIG``) replaces the search. Its keys are
listed in :mod:`fpgalink.cli.settings`.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fpgalink.protocol.robot import BOARD_NAME
from fpgalink.protocol.tomlfile import TomlFileError, load_toml

__all__ = [
    "CONFIG_KEYS",
    "CONFIG_NAME",
    "ConfigError",
    "Endpoint",
    "blank",
    "check_name",
    "config_paths",
    "config_ports",
    "env_switch",
    "load_config",
    "parse_ports",
    "seconds",
    "switch",
    "whole",
]


class ConfigError(ValueError):
    """A config file, a port list or a value in them that cannot be used: the message says
    which and why, on one line."""


CONFIG_NAME = "fpgalink.toml"
CONFIG_KEYS = frozenset({"port", "ports", "baud", "timeout", "retries", "wire_crc", "board",
                         "robot"})
#: ``NAME=URL``: a board name (:data:`~fpgalink.protocol.robot.BOARD_NAME`) before the first
#: ``=``; a URL's own ``=`` comes after ``://`` or ``?``, which no name holds.
_NAMED = re.compile(rf"^({BOARD_NAME.pattern})=(.*)$", re.DOTALL)


@dataclass(frozen=True, slots=True)
class Endpoint:
    name: str  #: ``L``/``R`` when named (``--port L=URL``, a ``[ports]`` table); else 0, 1…
    url: str


def parse_ports(values: tuple[str, ...] | list[str], where: str = "--port"
                ) -> tuple[Endpoint, ...]:
    """``URL`` or ``NAME=URL`` items. A name is letters, digits, ``_`` and ``-`` before the
    first ``=`` — so ``emu://?seed=3`` is a URL, not a name."""
    named: list[tuple[str, str]] = []
    for index, value in enumerate(values):
        match = _NAMED.match(value)
        named.append((match.group(1), match.group(2)) if match else (str(index), value))
    return _endpoints(named, where)


def _endpoints(named: list[tuple[str, str]], where: str) -> tuple[Endpoint, ...]:
    """(name, URL) pairs as endpoints: every URL non-blank, every name given once."""
    endpoints: list[Endpoint] = []
    for name, url in named:
        if not url.strip():
            raise ConfigError(f"{where} {name}: empty port")
        endpoints.append(Endpoint(name, url.strip()))
    names = [e.name for e in endpoints]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ConfigError(f"{where}: board name {duplicates[0]!r} given twice")
    return tuple(endpoints)


def config_paths(cwd: Path | None = None) -> list[Path]:
    """Where a config file is looked for, first found wins."""
    base = Path(os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config")
    return [(cwd or Path.cwd()) / CONFIG_NAME, base / "fpgalink" / CONFIG_NAME]


def blank(value: str | None) -> bool:
    """Given, but nothing in it but spaces (``--config ""``, ``FPGALINK_PORT="  "``)."""
    return value is not None and not value.strip()


def load_config(explicit: str | None) -> tuple[dict[str, Any], Path | None]:
    env = os.environ.get("FPGALINK_CONFIG")
    if blank(explicit):
        raise ConfigError("--config: empty file name (leave the option out to search for "
                       "fpgalink.toml)")
    if explicit:
        paths = [Path(explicit)]
    elif env and blank(env):
        raise ConfigError("environment FPGALINK_CONFIG is blank: name a file or unset it")
    elif env:
        paths = [Path(env)]
    else:
        paths = [p for p in config_paths() if p.is_file()][:1]
    for path in paths:
        try:
            return load_toml(str(path), f"config {path}"), path
        except TomlFileError as exc:
            raise ConfigError(str(exc)) from None
    return {}, None


def config_ports(config: Mapping[str, Any], path: Path) -> tuple[Endpoint, ...]:
    single, table = config.get("port"), config.get("ports")
    if single is not None and table is not None:
        raise ConfigError(f"config {path}: give port or [ports], not both")
    if isinstance(single, str):
        return parse_ports([single], f"config {path}: port")
    if isinstance(table, dict) and all(isinstance(v, str) for v in table.values()):
        # The keys are the names: taken as they are, never parsed again as NAME=URL.
        for key in table:
            check_name(key, f"config {path}: [ports] key")
        return _endpoints(list(table.items()), f"config {path}: [ports]")
    if single is not None or table is not None:
        raise ConfigError(f"config {path}: port must be a URL, [ports] a table of NAME = URL")
    return ()


def check_name(name: object, where: str) -> str:
    if not isinstance(name, str) or not BOARD_NAME.fullmatch(name):
        shown = repr(name) if len(repr(name)) <= 40 else repr(name)[:37] + "..."
        raise ConfigError(f"{where} {shown}: a board name is letters, digits, _ and - "
                       "(such as L)")
    return name


def whole(value: object, name: str, where: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ConfigError(f"{where}: {name} must be a whole number from {low:,} to {high:,}, "
                       f"got {value!r}")
    return value


def env_switch(text: str, where: str) -> bool:
    """An environment variable's on/off value: ``1`` or ``0``, nothing else."""
    if text not in ("0", "1"):
        raise ConfigError(f"{where}: {text!r} is not 0 or 1")
    return text == "1"


def switch(value: object, name: str, where: str) -> bool:
    """A config file's on/off value: TOML's ``true`` or ``false``, nothing else."""
    if not isinstance(value, bool):
        raise ConfigError(f"{where}: {name} must be true or false, got {value!r}")
    return value


def seconds(value: object, name: str, where: str, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or \
            not (math.isfinite(value) and low <= value <= high):
        raise ConfigError(f"{where}: {name} must be a number of seconds from {low:g} to {high:g}, "
                       f"got {value!r}")
    return float(value)
