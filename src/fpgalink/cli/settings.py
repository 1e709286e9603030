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

import contextlib
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fpgalink import config as _config
from fpgalink.cli.output import CliError, ExitCode
from fpgalink.config import (
    CONFIG_KEYS,
    ConfigError,
    Endpoint,
    config_paths,
)
from fpgalink.config import blank as _blank
from fpgalink.config import check_name as _check_name
from fpgalink.config import config_ports as _config_ports
from fpgalink.config import env_switch as _env_switch
from fpgalink.config import load_config as _load_config
from fpgalink.config import seconds as _seconds
from fpgalink.config import switch as _switch
from fpgalink.config import whole as _whole
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


@contextlib.contextmanager
def _as_cli_error() -> Iterator[None]:
    """The config module's errors as the CLI's bad-input errors (exit 2), same text."""
    try:
        yield
    except ConfigError as exc:
        raise CliError(str(exc), ExitCode.BAD_INPUT) from None


def parse_ports(values: tuple[str, ...] | list[str], where: str = "--port"
                ) -> tuple[Endpoint, ...]:
    """``URL`` or ``NAME=URL`` items (:func:`fpgalink.config.parse_ports`)."""
    with _as_cli_error():
        return _config.parse_ports(values, where)


@dataclass
class Settings:
    """The resolved settings, each with where it came from."""

    endpoints: tuple[Endpoint, ...]
    baud: int
    timeout: float
    retries: int
    wire_crc: bool
    verbose: int
    board: str | None
    robot: Path | None
    config_file: Path | None
    sources: dict[str, str] = field(default_factory=dict)
    #: go on with a board whose firmware speaks another protocol declaration (the command
    #: line only: a file or an environment that always allows it would hide it)
    allow_mismatch: bool = False

    @property
    def emulated(self) -> bool:
        """No port anywhere: commands run against the built-in emulator."""
        return self.sources.get("port") == DEFAULT


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
    with _as_cli_error():
        return _resolve_settings(given, before)


def _resolve_settings(given: Mapping[str, Any], before: Mapping[str, Any]) -> Settings:
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
    wire_crc = _switch(pick("wire_crc", "FPGALINK_WIRE_CRC", _env_switch, False), "wire_crc",
                       sources["wire_crc"])
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
    allow_mismatch = bool(given.get("allow_mismatch") or before.get("allow_mismatch"))
    return Settings(ports, baud, timeout, retries, bool(wire_crc), verbose, board, robot, path,
                    sources, allow_mismatch)
