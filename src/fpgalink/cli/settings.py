"""Where each connection setting comes from: the command line (after the command, then
before it), the environment, a config file, or the default — in that order — and which one
it was, for ``fpgalink-cli config`` and for errors that say what to change.

The config file is ``fpgalink.toml`` in the working directory, else
``$XDG_CONFIG_HOME/fpgalink/fpgalink.toml`` (``~/.config/fpgalink/fpgalink.toml``); ``--config
FILE`` or ``FPGALINK_CONFIG`` names one explicitly. Its keys::

    port = "/dev/serial/by-id/usb-Digilent_…"   # one board, or per board:
    [ports]
    L = "/dev/serial/by-id/…-if01-port0"
    R = "/dev/serial/by-id/…-if01-port0"
    baud = 1000000
    timeout = 0.05       # per-try request timeout, s
    retries = 8          # tries per request
    board = "L"          # the board one-board commands use when several are configured
    robot = "robot.toml" # the robot description (relative to this file)
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fpgalink.cli.output import CliError, ExitCode
from fpgalink.protocol.robot import BOARD_NAME
from fpgalink.protocol.tomlfile import TomlFileError, load_toml
from fpgalink.protocol.wire import MAX_BAUD, MIN_BAUD

__all__ = [
    "COMMAND_LINE",
    "DEFAULT",
    "Endpoint",
    "Settings",
    "config_paths",
    "parse_ports",
    "resolve_settings",
]

COMMAND_LINE = "command line"
DEFAULT = "default"
EMULATOR_URL = "emu://"
CONFIG_NAME = "fpgalink.toml"
CONFIG_KEYS = frozenset({"port", "ports", "baud", "timeout", "retries", "board", "robot"})
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
            raise CliError(f"{where} {name}: empty port", ExitCode.BAD_INPUT)
        endpoints.append(Endpoint(name, url.strip()))
    names = [e.name for e in endpoints]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise CliError(f"{where}: board name {duplicates[0]!r} given twice", ExitCode.BAD_INPUT)
    return tuple(endpoints)


@dataclass
class Settings:
    """The resolved settings, each with where it came from."""

    endpoints: tuple[Endpoint, ...]
    baud: int
    timeout: float
    retries: int
    verbose: int
    board: str | None
    robot: Path | None
    config_file: Path | None
    sources: dict[str, str] = field(default_factory=dict)

    @property
    def emulated(self) -> bool:
        """No port anywhere: commands run against the built-in emulator."""
        return self.sources.get("port") == DEFAULT


def config_paths(cwd: Path | None = None) -> list[Path]:
    """Where a config file is looked for, first found wins."""
    base = Path(os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config")
    return [(cwd or Path.cwd()) / CONFIG_NAME, base / "fpgalink" / CONFIG_NAME]


def _blank(value: str | None) -> bool:
    """Given, but nothing in it but spaces (``--config ""``, ``FPGALINK_PORT="  "``)."""
    return value is not None and not value.strip()


def _load_config(explicit: str | None) -> tuple[dict[str, Any], Path | None]:
    env = os.environ.get("FPGALINK_CONFIG")
    if _blank(explicit):
        raise CliError("--config: empty file name (leave the option out to search for "
                       "fpgalink.toml)", ExitCode.BAD_INPUT)
    if explicit:
        paths = [Path(explicit)]
    elif env and _blank(env):
        raise CliError("environment FPGALINK_CONFIG is blank: name a file or unset it",
                       ExitCode.BAD_INPUT)
    elif env:
        paths = [Path(env)]
    else:
        paths = [p for p in config_paths() if p.is_file()][:1]
    for path in paths:
        try:
            return load_toml(str(path), f"config {path}"), path
        except TomlFileError as exc:
            raise CliError(str(exc), ExitCode.BAD_INPUT) from None
    return {}, None


def _config_ports(config: Mapping[str, Any], path: Path) -> tuple[Endpoint, ...]:
    single, table = config.get("port"), config.get("ports")
    if single is not None and table is not None:
        raise CliError(f"config {path}: give port or [ports], not both", ExitCode.BAD_INPUT)
    if isinstance(single, str):
        return parse_ports([single], f"config {path}: port")
    if isinstance(table, dict) and all(isinstance(v, str) for v in table.values()):
        # The keys are the names: taken as they are, never parsed again as NAME=URL.
        for key in table:
            _check_name(key, f"config {path}: [ports] key")
        return _endpoints(list(table.items()), f"config {path}: [ports]")
    if single is not None or table is not None:
        raise CliError(f"config {path}: port must be a URL, [ports] a table of NAME = URL",
                       ExitCode.BAD_INPUT)
    return ()


def _check_name(name: object, where: str) -> str:
    if not isinstance(name, str) or not BOARD_NAME.fullmatch(name):
        shown = repr(name) if len(repr(name)) <= 40 else repr(name)[:37] + "..."
        raise CliError(f"{where} {shown}: a board name is letters, digits, _ and - "
                       "(such as L)", ExitCode.BAD_INPUT)
    return name


def _whole(value: object, name: str, where: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise CliError(f"{where}: {name} must be a whole number from {low:,} to {high:,}, "
                       f"got {value!r}", ExitCode.BAD_INPUT)
    return value


def _seconds(value: object, name: str, where: str, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or \
            not (math.isfinite(value) and low <= value <= high):
        raise CliError(f"{where}: {name} must be a number of seconds from {low:g} to {high:g}, "
                       f"got {value!r}", ExitCode.BAD_INPUT)
    return float(value)


#: How strongly each kind of source holds: a board chosen in a weaker place than the ports
#: came from may name none of them, and then it does not apply.
_STRENGTH = {COMMAND_LINE: 3, "environment": 2, "config file": 1, DEFAULT: 0}


def _strength(source: str) -> int:
    return next((v for k, v in _STRENGTH.items() if source.startswith(k)), 0)


def _board_for_ports(board: str | None, ports: tuple[Endpoint, ...],
                     sources: dict[str, str]) -> str | None:
    """An explicit ``--port`` (or ``FPGALINK_PORT``) wins over the board selection of a
    weaker source: ``board = "L"`` in the config file picks among the file's ports, and is
    set aside when the ports given on the command line have no board L (``config`` says
    so)."""
    if board is None or any(e.name == board for e in ports):
        return board
    if _strength(sources["board"]) < _strength(sources["port"]):
        where = "--port" if sources["port"] == COMMAND_LINE else sources["port"]
        sources["board"] = (f"{sources['board']}, set aside: the ports from {where} have "
                            f"no board {board}")
        return None
    return board


def resolve_settings(given: Mapping[str, Any], before: Mapping[str, Any]) -> Settings:
    """Settings from the options given after the command (``given``), before it
    (``before``), the environment, the config file and the defaults."""
    explicit = next((v for v in (given.get("config"), before.get("config")) if v is not None),
                    None)
    config, path = _load_config(explicit)
    file_source = f"config file {path}" if path else ""
    unknown = sorted(set(config) - CONFIG_KEYS)
    if unknown:
        raise CliError(f"config {path}: unknown key {unknown[0]!r} (known: "
                       f"{', '.join(sorted(CONFIG_KEYS))})", ExitCode.BAD_INPUT)
    sources: dict[str, str] = {}

    def pick(name: str, env: str | None, convert: Any, default: Any) -> Any:
        for values in (given, before):
            if values.get(name) not in (None, ()):
                sources[name] = COMMAND_LINE
                return values[name]
        if env and os.environ.get(env):
            sources[name] = f"environment {env}"
            return convert(os.environ[env], f"environment {env}")
        if name in config:
            sources[name] = file_source
            return config[name]
        sources[name] = DEFAULT
        return default

    def env_int(text: str, where: str) -> int:
        try:
            return int(text)
        except ValueError:
            raise CliError(f"{where}: {text!r} is not a whole number", ExitCode.BAD_INPUT) from None

    ports: tuple[Endpoint, ...] = ()
    for values in (given, before):
        if values.get("ports"):
            ports, sources["port"] = parse_ports(values["ports"]), COMMAND_LINE
            break
    else:
        if _blank(os.environ.get("FPGALINK_PORT") or None):
            raise CliError("environment FPGALINK_PORT is blank: give a port (a device path, "
                           "socket://HOST:PORT, emu://, or NAME=URL words) or unset it",
                           ExitCode.BAD_INPUT)
        if os.environ.get("FPGALINK_PORT"):
            ports = parse_ports(os.environ["FPGALINK_PORT"].split(), "FPGALINK_PORT")
            sources["port"] = "environment FPGALINK_PORT"
        elif path is not None and (ports := _config_ports(config, path)):
            sources["port"] = file_source
        else:
            ports, sources["port"] = (Endpoint("0", EMULATOR_URL),), DEFAULT
    baud = _whole(pick("baud", "FPGALINK_BAUD", env_int, 1_000_000), "baud", sources["baud"],
                  MIN_BAUD, MAX_BAUD)
    timeout = _seconds(pick("timeout", None, None, 0.05), "timeout", sources["timeout"],
                       1e-4, 60.0)
    retries = _whole(pick("retries", None, None, 8), "retries", sources["retries"], 1, 1000)
    board = pick("board", "FPGALINK_BOARD", lambda text, _where: text, None)
    robot = pick("robot", None, None, None)
    for name, value in (("board", board), ("robot", robot)):
        if value is not None and not (isinstance(value, str) and value.strip()):
            raise CliError(f"{sources[name]}: {name} must be a non-empty string, got {value!r}",
                           ExitCode.BAD_INPUT)
    if board is not None:
        _check_name(board, f"{sources['board']}: board")
    board = _board_for_ports(board, ports, sources)
    if robot is not None:
        robot_path = Path(str(robot))
        if sources["robot"] == file_source and path is not None and not robot_path.is_absolute():
            robot_path = path.parent / robot_path
        robot = robot_path
    verbose = max(int(given.get("verbose") or 0), int(before.get("verbose") or 0))
    return Settings(ports, baud, timeout, retries, verbose, board, robot, path, sources)
