"""``config``: the connection settings a command would use here, and where each came from
(command line, environment, config file, default) — the first thing to run when a command
talks to the wrong port."""

from __future__ import annotations

from typing import Any

import click

from fpgalink.cli.formats import (
    Column,
    console_width,
    emit_document,
    emit_rows,
    format_option,
)
from fpgalink.cli.options import ConnectionOptions, connection_options
from fpgalink.cli.output import EXIT_CODES_HELP, ExitCode, echo_out
from fpgalink.cli.settings import Settings, config_paths

__all__ = ["config", "settings_rows", "settings_values"]


def settings_rows(settings: Settings) -> list[tuple[str, str, str]]:
    """(setting, value, source) for every setting, in the order a user reads them."""
    ports = " ".join(f"{e.name}={e.url}" if len(settings.endpoints) > 1 or not
                     e.name.isdigit() else e.url for e in settings.endpoints)
    src = settings.sources
    return [
        ("port", ports, src["port"]),
        ("board", settings.board or "-", src["board"]),
        ("baud", f"{settings.baud}", src["baud"]),
        ("timeout", f"{settings.timeout:g} s", src["timeout"]),
        ("retries", f"{settings.retries}", src["retries"]),
        ("wire crc", "on" if settings.wire_crc else "off", src["wire_crc"]),
        ("robot", str(settings.robot) if settings.robot else "-", src["robot"]),
    ]


def settings_values(settings: Settings) -> dict[str, dict[str, Any]]:
    """Every setting as JSON has it: numbers as numbers, the unit in the key."""
    src = settings.sources
    return {
        "port": {"value": [{"name": e.name, "url": e.url} for e in settings.endpoints],
                 "source": src["port"]},
        "board": {"value": settings.board, "source": src["board"]},
        "baud": {"value": settings.baud, "source": src["baud"]},
        "timeout_s": {"value": settings.timeout, "source": src["timeout"]},
        "retries": {"value": settings.retries, "source": src["retries"]},
        "wire_crc": {"value": settings.wire_crc, "source": src["wire_crc"]},
        "robot": {"value": str(settings.robot) if settings.robot else None,
                  "source": src["robot"]},
    }


@click.command(epilog=EXIT_CODES_HELP)
@format_option
@connection_options(multi=True, announce=False)
def config(fmt: str, conn: ConnectionOptions) -> int:
    """Show the connection settings in force and where each came from.

    Precedence: options after the command, options before it, the environment
    (FPGALINK_PORT, FPGALINK_BAUD, FPGALINK_BOARD), the config file, the defaults. A board
    chosen in a weaker place than the ports (board = "L" in the file, ports from --port)
    applies only if those ports have that board. The config file is --config FILE,
    FPGALINK_CONFIG, else the first of ./fpgalink.toml and ~/.config/fpgalink/fpgalink.toml
    (XDG_CONFIG_HOME is honoured).
    """
    settings = conn.settings
    rows = settings_rows(settings)
    searched = [str(p) for p in config_paths()]
    if fmt == "json":
        emit_document({
            "config_file": str(settings.config_file) if settings.config_file else None,
            "searched": searched,
            "emulated": settings.emulated,
            "settings": settings_values(settings),
        })
        return ExitCode.OK
    if fmt == "csv":
        columns = [Column("setting", "setting"), Column("value", "value"),
                   Column("source", "source")]
        emit_rows(fmt, columns, [{"setting": name, "value": value, "source": source}
                                 for name, value, source in rows])
        return ExitCode.OK
    if settings.config_file is not None:
        echo_out(f"config file: {settings.config_file}")
    else:
        echo_out(f"config file: none (looked for {' and '.join(searched)})")
    # One port per line; a value too long for the terminal beside its source has the
    # source on the line below, so nothing is cut and the other rows stay aligned.
    lines = [(name, value.split(" ") if name == "port" else [value], source)
             for name, value, source in rows]
    width = max(len(name) for name, _, _ in rows)
    room = console_width() - width - 6
    fitting = [len(v) for _, values, source in lines for v in values
               if len(v) + len(source) + 2 <= room]
    value_width = max(fitting, default=0)
    for name, values, source in lines:
        label = name
        for i, value in enumerate(values):
            last = i == len(values) - 1
            if not last:
                echo_out(f"  {label:<{width}}  {value}")
            elif len(value) <= value_width:
                echo_out(f"  {label:<{width}}  {value:<{value_width}}  ({source})")
            else:
                echo_out(f"  {label:<{width}}  {value}")
                echo_out(f"  {'':<{width}}  {'':<{value_width}}  ({source})")
            label = ""
    if settings.emulated:
        echo_out("no port configured: commands run against the built-in emulator (emu://)")
    return ExitCode.OK
