"""``param get|set|list|load|dump``: the SPEC §5 parameters, validated on the host first."""

from __future__ import annotations

import datetime as dt
import os
import sys
import tomllib
from pathlib import Path
from typing import Any

import click
from rich.table import Table

from fpgalink.cli.options import ConnectionOptions, connection_options
from fpgalink.cli.output import (
    EXIT_CODES_HELP,
    CliError,
    ExitCode,
    classify,
    echo_out,
    format_value,
    table_console,
)
from fpgalink.cli.session import run
from fpgalink.errors import ParameterError
from fpgalink.protocol import PARAMETERS, Param, ParamType, Scope, resolve
from fpgalink.protocol.params import BOARD, channel_name

__all__ = ["param", "parse_param_file", "parse_value", "render_toml"]

_CHANNEL = click.option("--channel", "-c", type=click.Choice(["A", "B"], case_sensitive=False),
                        help="Channel of a per-channel parameter (or suffix the name: ...A).")


def _resolve(name: str, channel: str | None) -> tuple[Param, int]:
    try:
        return resolve(name, channel)
    except ParameterError as exc:
        raise CliError(str(exc), ExitCode.BAD_INPUT) from None


def parse_value(param: Param, channel: int, text: str) -> int | float:
    """Command-line text → the value as it will travel, or a one-line error naming the
    parameter and its valid range (exit 2)."""
    label = param.full_name(channel)
    kind = "an integer" if param.type is ParamType.INT else "a number"
    try:
        value: int | float = int(text) if param.type is ParamType.INT else float(text)
    except ValueError:
        try:
            value = float(text)
        except ValueError:
            raise CliError(f"{label}: {text!r} is not {kind}; valid: {param.range_text}",
                           ExitCode.BAD_INPUT) from None
    return _coerce(param, channel, value)


def _coerce(param: Param, channel: int, value: object) -> int | float:
    try:
        return param.coerce(value)
    except ParameterError as exc:
        message = str(exc)
        label = param.full_name(channel)
        # coerce names the base parameter; say which channel too.
        if label != param.name:
            message = message.replace(param.name, label, 1)
        raise CliError(message, ExitCode.BAD_INPUT) from None


@click.group(epilog=EXIT_CODES_HELP)
def param() -> None:
    """Read and write board parameters (confirmed by the board's echo)."""


@param.command("get", epilog=EXIT_CODES_HELP)
@click.argument("name")
@_CHANNEL
@connection_options()
def get(name: str, channel: str | None, conn: ConnectionOptions) -> int:
    """Print the value of parameter NAME in force on the board (just the value: scriptable)."""
    p, code = _resolve(name, channel)
    value = run(_get(conn, p, code), conn.single.url)
    echo_out(format_value(value, p.type))
    return ExitCode.OK


async def _get(conn: ConnectionOptions, p: Param, code: int) -> int | float:
    async with conn.link(conn.single) as link:
        return await link.get_param(p.id, code)


@param.command("set", epilog=EXIT_CODES_HELP,
               context_settings={"ignore_unknown_options": True})
@click.argument("name")
@click.argument("value")
@_CHANNEL
@connection_options()
def set_(name: str, value: str, channel: str | None, conn: ConnectionOptions) -> int:
    """Set parameter NAME to VALUE; prints the value the board confirms is in force.

    The request is resent until the board's echo matches (--timeout, --retries). Negative
    values need no quoting: `param set IncSenzCountDirectionA -1`.
    """
    p, code = _resolve(name, channel)
    coerced = parse_value(p, code, value)
    confirmed = run(_set(conn, p, code, coerced), conn.single.url)
    echo_out(f"{p.full_name(code)} = {format_value(confirmed, p.type)}")
    return ExitCode.OK


async def _set(conn: ConnectionOptions, p: Param, code: int, value: int | float) -> int | float:
    async with conn.link(conn.single) as link:
        return await link.set_param(p.id, value, code)


@param.command("list", epilog=EXIT_CODES_HELP)
@connection_options()
def list_(conn: ConnectionOptions) -> int:
    """Table of every parameter: id, name, scope, type, range and the board's values."""
    values = run(_read(conn), conn.single.url)
    table = Table(title=f"Parameters on {conn.single.url}")
    for column in ("id", "name", "scope", "type", "range", "unit"):
        table.add_column(column, justify="right" if column == "id" else "left")
    for column in ("board", "A", "B"):
        table.add_column(column, justify="right")
    for p in PARAMETERS:
        if p.scope is Scope.BOARD:
            cells = [format_value(values[(p.id, BOARD)], p.type), "", ""]
        else:
            cells = ["", *(format_value(values[(p.id, c)], p.type) for c in (1, 2))]
        table.add_row(str(p.id), p.name, p.scope.name.lower(), p.type.name.lower(),
                      p.range_text, p.unit, *cells)
    table_console().print(table)
    return ExitCode.OK


async def _read(conn: ConnectionOptions) -> dict[tuple[int, int], int | float]:
    async with conn.link(conn.single) as link:
        return await link.read_params()


# --- files ------------------------------------------------------------------------------------


def render_toml(values: dict[tuple[int, int], int | float], source: str) -> str:
    """Parameter values as TOML: board parameters at the top, then ``[A]`` and ``[B]`` tables
    (the layout ``param load`` reads). Written by hand: the values are only numbers."""
    stamp = dt.datetime.now(dt.UTC).replace(microsecond=0).isoformat()
    lines = [f"# fpgalink parameters read from {source} at {stamp}",
             "# NAME = VALUE  # range, unit. Load with: fpgalink-cli param load FILE", ""]

    def line(p: Param, code: int) -> str:
        note = ", ".join(x for x in (p.range_text, p.unit) if x)
        return f"{p.name} = {format_value(values[(p.id, code)], p.type)}  # {note}"

    lines += [line(p, BOARD) for p in PARAMETERS if p.scope is Scope.BOARD]
    for code in (1, 2):
        lines += ["", f"[{channel_name(code)}]"]
        lines += [line(p, code) for p in PARAMETERS if p.scope is Scope.CHANNEL]
    return "\n".join(lines) + "\n"


def parse_param_file(text: str, source: str) -> list[tuple[Param, int, int | float]]:
    """TOML → validated ``(param, channel, value)`` list; any problem is a one-line error
    (exit 2) before anything is sent. Top level: board parameters or suffixed names
    (``Kp_Wheel_PidA``); tables ``[A]``/``[B]``: unsuffixed channel parameters."""
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CliError(f"{source}: not valid TOML: {exc}", ExitCode.BAD_INPUT) from None
    entries: list[tuple[str, str | None, Any]] = []
    for key, value in document.items():
        if isinstance(value, dict):
            if key.upper() not in ("A", "B"):
                raise CliError(f"{source}: unknown table [{key}]; use [A] or [B]",
                               ExitCode.BAD_INPUT)
            entries += [(name, key.upper(), v) for name, v in value.items()]
        else:
            entries.append((key, None, value))
    result: list[tuple[Param, int, int | float]] = []
    seen: set[tuple[int, int]] = set()
    for name, channel, value in entries:
        where = f"[{channel}] {name}" if channel else name
        try:
            p, code = resolve(name, channel)
        except ParameterError as exc:
            raise CliError(f"{source}: {where}: {exc}", ExitCode.BAD_INPUT) from None
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise CliError(f"{source}: {p.full_name(code)} = {value!r}: expected a number "
                           f"({p.range_text})", ExitCode.BAD_INPUT)
        if (p.id, code) in seen:
            raise CliError(f"{source}: {p.full_name(code)} given twice", ExitCode.BAD_INPUT)
        seen.add((p.id, code))
        try:
            coerced = p.coerce(value)
        except ParameterError as exc:
            raise CliError(f"{source}: {p.full_name(code)}: {exc}", ExitCode.BAD_INPUT) from None
        result.append((p, code, coerced))
    return result


@param.command("load", epilog=EXIT_CODES_HELP)
@click.argument("file", type=click.Path(dir_okay=False, allow_dash=True))
@connection_options()
def load(file: str, conn: ConnectionOptions) -> int:
    """Set every parameter in a TOML FILE ('-' for stdin), one at a time; each line is
    reported as confirmed or failed. All values are checked before the first is sent."""
    try:
        text = sys.stdin.read() if file == "-" else Path(file).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CliError(f"{file}: cannot read: {exc}", ExitCode.BAD_INPUT) from None
    entries = parse_param_file(text, file)
    if not entries:
        raise CliError(f"{file}: no parameters in the file", ExitCode.BAD_INPUT)
    return run(_load(conn, entries), conn.single.url)


async def _load(conn: ConnectionOptions, entries: list[tuple[Param, int, int | float]]) -> int:
    worst = ExitCode.OK
    async with conn.link(conn.single) as link:
        results = await link.sync_params(
            [(p.full_name(code), None, value) for p, code, value in entries]
        )
    by_name = {p.full_name(code): p for p, code, _ in entries}
    for result in results:
        p = by_name[result.name]
        if result.ok:
            assert result.confirmed is not None
            echo_out(f"ok      {result.name} = {format_value(result.confirmed, p.type)}")
            continue
        assert result.error is not None
        error = classify(result.error, conn.single.url)
        echo_out(f"failed  {result.name} = {format_value(result.requested, p.type)}: "
                 f"{error.format_message()}")
        worst = max(worst, ExitCode(error.exit_code))
    ok = sum(r.ok for r in results)
    if worst is not ExitCode.OK:
        raise CliError(f"{len(results) - ok} of {len(results)} parameters failed", worst)
    return ExitCode.OK


@param.command("dump", epilog=EXIT_CODES_HELP)
@click.argument("file", type=click.Path(dir_okay=False, allow_dash=True))
@connection_options()
def dump(file: str, conn: ConnectionOptions) -> int:
    """Read every parameter from the board into a TOML FILE ('-' for stdout) that
    `param load` accepts. Nothing is written unless every value was read."""
    values = run(_read(conn), conn.single.url)
    text = render_toml(values, conn.single.url)
    if file == "-":
        sys.stdout.write(text)
        sys.stdout.flush()
        return ExitCode.OK
    target = Path(file)
    temporary = target.with_name(f".{target.name}.tmp{os.getpid()}")
    try:
        temporary.write_text(text, encoding="utf-8")
        temporary.replace(target)
    except OSError as exc:
        temporary.unlink(missing_ok=True)
        raise CliError(f"{file}: cannot write: {exc.strerror}", ExitCode.FAILURE) from None
    click.echo(f"wrote {len(values)} values to {file}", err=True)
    return ExitCode.OK
