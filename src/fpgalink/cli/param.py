"""``param get|set|list|load|dump``: the SPEC §5 parameters, validated on the host first."""

from __future__ import annotations

import contextlib
import datetime as dt
import math
import os
import stat
import sys
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from fpgalink.cli.files import check_output, force_option, write_file
from fpgalink.cli.formats import (
    Column,
    console_width,
    emit_document,
    emit_rows,
    fit_table,
    format_option,
    print_renderable,
    table_width,
    write_out,
)
from fpgalink.cli.options import ConnectionOptions, Endpoint, connection_options
from fpgalink.cli.output import (
    EXIT_CODES_HELP,
    CliError,
    ExitCode,
    SignedNumbers,
    classify,
    echo_out,
    format_value,
    note,
    number,
)
from fpgalink.cli.session import gather_all, run
from fpgalink.errors import FpgalinkError, ParameterError
from fpgalink.protocol import PARAMETERS, Param, ParamType, Scope, describe_identity, resolve
from fpgalink.protocol.paramfile import Setting, parse_parameter_file, render_parameter_file
from fpgalink.protocol.params import BOARD, iter_addresses
from fpgalink.protocol.tomlfile import TomlFileError, read_bounded

if TYPE_CHECKING:
    from click.shell_completion import CompletionItem

__all__ = ["SHIPPED_SETS", "param", "parse_param_file", "parse_value", "write_output"]

#: Parameter sets that ship with the package, loadable by name (``param load seed-high``).
SHIPPED_SETS = "fpgalink.parameter_sets"


def _names(ctx: click.Context, param: click.Parameter, incomplete: str) -> list[str]:
    """Shell completion: parameter names, with and without the channel suffix."""
    names = [p.name for p in PARAMETERS]
    names += [p.name + c for p in PARAMETERS if p.scope is Scope.CHANNEL for c in "AB"]
    return [n for n in names if n.lower().startswith(incomplete.lower())]


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
    try:
        return param.coerce(value)
    except ParameterError as exc:
        # coerce names the base parameter; say which channel too.
        message = str(exc).replace(param.name, label, 1) if label != param.name else str(exc)
        raise CliError(message, ExitCode.BAD_INPUT) from None


@click.group(epilog=EXIT_CODES_HELP)
def param() -> None:
    """Read and write board parameters (confirmed by the board's echo)."""


def _channel_name(code: int) -> str | None:
    return None if code == BOARD else "AB"[code - 1]


def _value_document(p: Param, code: int, value: int | float, **extra: Any) -> dict[str, Any]:
    return {"name": p.full_name(code), "param_id": p.id, "channel": _channel_name(code),
            "value": number(value, p.type), "unit": p.unit or None, **extra}


def _emit_value(fmt: str, p: Param, code: int, value: int | float, table_text: str,
                **extra: Any) -> None:
    """One parameter value: ``table_text`` for people, a JSON object or a CSV row."""
    if fmt == "table":
        echo_out(table_text)
        return
    document = _value_document(p, code, value, **extra)
    if fmt == "json":
        emit_document(document)
    else:
        emit_rows(fmt, [Column(k, k) for k in document], [document])


@param.command("get", epilog=EXIT_CODES_HELP)
@click.argument("name", shell_complete=_names)
@_CHANNEL
@format_option
@connection_options()
def get(name: str, channel: str | None, fmt: str, conn: ConnectionOptions) -> int:
    """Print the value of parameter NAME in force on the board (just the value: scriptable)."""
    p, code = _resolve(name, channel)
    value = run(_get(conn, p, code), conn.single.url)
    _emit_value(fmt, p, code, value, format_value(value, p.type))
    return ExitCode.OK


async def _get(conn: ConnectionOptions, p: Param, code: int) -> int | float:
    async with conn.link(conn.single) as link:
        return await link.get_param(p.id, code)


@param.command("set", cls=SignedNumbers, epilog=EXIT_CODES_HELP)
@click.argument("name", shell_complete=_names)
@click.argument("value")
@_CHANNEL
@format_option
@connection_options()
def set_(name: str, value: str, channel: str | None, fmt: str, conn: ConnectionOptions) -> int:
    """Set parameter NAME to VALUE; prints the value the board confirms is in force.

    The request is resent until the board's echo matches exactly (--timeout, --retries);
    another value in the echo is not a confirmation (exit 3). Negative values need no
    quoting: `param set IncSenzCountDirectionA -1`.
    """
    p, code = _resolve(name, channel)
    coerced = parse_value(p, code, value)
    conn.note_ephemeral()
    confirmed = run(_set(conn, p, code, coerced), conn.single.url)
    _emit_value(fmt, p, code, confirmed, f"{p.full_name(code)} = "
                f"{format_value(confirmed, p.type)}", confirmed=True)
    return ExitCode.OK


async def _set(conn: ConnectionOptions, p: Param, code: int, value: int | float) -> int | float:
    async with conn.link(conn.single) as link:
        return await link.set_param(p.id, value, code)


#: param list's columns; the name and the values are never left out, the rest go first to
#: last when the table does not fit the terminal.
LIST_COLUMNS = (
    Column("id", "id", justify="right", drop=2),
    Column("name", "name"),
    Column("scope", "scope", drop=5),
    Column("type", "type", drop=4),
    Column("range", "range", drop=1),
    Column("unit", "unit", drop=3),
    Column("board", "board", justify="right"),
    Column("A", "A", justify="right"),
    Column("B", "B", justify="right"),
)
#: Who the board said it is (docs/protocol.md §8): in the table's title; in JSON and CSV on
#: every row (``board_protocol`` ``null`` for a seed board).
LIST_IDENTITY_COLUMNS = (Column("board_identity", "board_identity"),
                         Column("board_protocol", "board_protocol"))
#: The range as numbers, for scripts (the table's ``range`` says it in words): ``null`` for
#: an unbounded side; ``allowed`` the discrete set where there is one.
LIST_LIMIT_COLUMNS = (
    Column("min", "min"), Column("min_exclusive", "min_exclusive"), Column("max", "max"),
    Column("allowed", "allowed"),
)


@param.command("list", epilog=EXIT_CODES_HELP)
@format_option
@connection_options(multi=True)
def list_(fmt: str, conn: ConnectionOptions) -> int:
    """Table of every parameter: id, name, scope, type, range and the board's values.

    With several boards configured and no --board, every board's values: a column per
    board (one table per board when they do not fit side by side); JSON and CSV rows then
    name their board (board_name).
    """
    endpoints = conn.selected
    if len(endpoints) == 1:
        board = run(_read(conn, endpoints[0]), endpoints[0].url)
        _list_one(fmt, board, f"Parameters on {endpoints[0].url}")
        return ExitCode.OK
    by_board = run(_read_all(conn, endpoints))
    if fmt != "table":
        rows = [{"board_name": e.name, **row} for e in endpoints
                for row in _rows(by_board[e.name])]
        columns = (Column("board_name", "board_name"), *LIST_COLUMNS, *LIST_LIMIT_COLUMNS,
                   *LIST_IDENTITY_COLUMNS)
        emit_rows(fmt, columns, rows)
        return ExitCode.OK
    if not _list_side_by_side(endpoints, by_board):
        for endpoint in endpoints:
            _list_one(fmt, by_board[endpoint.name],
                      f"Parameters on {endpoint.name} ({endpoint.url})")
    return ExitCode.OK


@dataclass(frozen=True)
class BoardParameters:
    """One board's parameters as read, and who it said it is."""

    values: dict[tuple[int, int], int | float]
    identity: str  #: :func:`~fpgalink.protocol.describe_identity`'s line
    protocol: str | None  #: its declaration hash (16 hex digits), ``None`` when unknown


def _rows(board: BoardParameters) -> list[dict[str, Any]]:
    """One row per parameter as JSON has it, with its values on one board (and the board's
    identity, which JSON and CSV repeat on every row)."""
    values = board.values
    rows = []
    for p in PARAMETERS:
        row: dict[str, Any] = {"id": p.id, "name": p.name, "scope": p.scope.name.lower(),
                               "type": p.type.name.lower(), "range": p.range_text,
                               "unit": p.unit or None, "board": None, "A": None, "B": None,
                               "min": _limit(p.minimum, p.type), "min_exclusive": p.min_exclusive,
                               "max": _limit(p.maximum, p.type),
                               "allowed": list(p.allowed) if p.allowed is not None else None}
        if p.scope is Scope.BOARD:
            row["board"] = number(values[(p.id, BOARD)], p.type)
        else:
            row["A"], row["B"] = (number(values[(p.id, c)], p.type) for c in (1, 2))
        row["board_identity"], row["board_protocol"] = board.identity, board.protocol
        rows.append(row)
    return rows


def _list_one(fmt: str, board: BoardParameters, title: str) -> None:
    rows = _rows(board)
    if fmt == "table":
        kinds = {p.name: p.type for p in PARAMETERS}
        rows = [{**row, **{k: "" if row[k] is None else format_value(row[k], kinds[row["name"]])
                           for k in ("board", "A", "B")}} for row in rows]
        title = f"{title}\n{board.identity}"
    columns = LIST_COLUMNS if fmt == "table" else (*LIST_COLUMNS, *LIST_LIMIT_COLUMNS,
                                                   *LIST_IDENTITY_COLUMNS)
    emit_rows(fmt, columns, rows, title=title)


def _list_side_by_side(endpoints: tuple[Endpoint, ...],
                       by_board: dict[str, BoardParameters]) -> bool:
    """Every board's values in one table, a row per parameter and channel
    (``Kp_Wheel_PidA``) and a column per board, if that fits the terminal with at most the
    descriptive columns left out; ``False`` (nothing printed) when it does not."""
    columns = [c for c in LIST_COLUMNS if c.key not in ("board", "A", "B")]
    columns += [Column(e.name, e.name, justify="right") for e in endpoints]
    rows = []
    for p, code in iter_addresses():
        rows.append([str(p.id), p.full_name(code), p.scope.name.lower(), p.type.name.lower(),
                     p.range_text, p.unit or "",
                     *(format_value(by_board[e.name].values[(p.id, code)], p.type)
                       for e in endpoints)])
    needed = [max([len(c.header), *(len(r[i]) for r in rows)])
              for i, c in enumerate(columns) if not c.drop]
    if table_width(needed) > console_width():
        return False
    boards = ", ".join(f"{e.name} ({e.url})" for e in endpoints)
    identities = "\n".join(f"{e.name}: {by_board[e.name].identity}" for e in endpoints)
    print_renderable(fit_table(columns, rows, console_width(),
                               f"Parameters on {boards}\n{identities}"))
    return True


def _limit(value: float, kind: ParamType) -> int | float | None:
    if not math.isfinite(value):
        return None
    return int(value) if kind is ParamType.INT else number(value, kind)


async def _read(conn: ConnectionOptions, endpoint: Endpoint | None = None
                ) -> BoardParameters:
    async with conn.link(endpoint or conn.single) as link:
        values = await link.read_params()
        identity = link.identification.identity
        return BoardParameters(values, describe_identity(identity, link.identification.known),
                               None if identity is None else identity.digest)


async def _read_all(conn: ConnectionOptions, endpoints: tuple[Endpoint, ...]
                    ) -> dict[str, BoardParameters]:
    """Every board's values, read at once; a board's failure names its port."""

    async def one(endpoint: Endpoint) -> BoardParameters:
        try:
            return await _read(conn, endpoint)
        except FpgalinkError as exc:
            raise classify(exc, f"{endpoint.name} ({endpoint.url})") from None

    found = await gather_all(*(one(e) for e in endpoints))
    return {e.name: values for e, values in zip(endpoints, found, strict=True)}


# --- files ------------------------------------------------------------------------------------


def parse_param_file(text: str, source: str) -> list[Setting]:
    """The file's settings, or a one-line error (exit 2) before anything is sent."""
    try:
        return parse_parameter_file(text, source)
    except ParameterError as exc:
        raise CliError(str(exc), ExitCode.BAD_INPUT) from None


def shipped_sets() -> list[str]:
    """The names of the parameter sets that ship with the package."""
    folder = resources.files(SHIPPED_SETS)
    return sorted(p.name.removesuffix(".toml") for p in folder.iterdir()
                  if p.name.endswith(".toml"))


def _read_settings(file: str) -> tuple[str, str]:
    """The text of FILE: '-' is stdin, a name without a path is a shipped set."""
    try:
        if file == "-":
            return read_bounded(sys.stdin.buffer, "stdin"), "stdin"
        if not Path(file).exists() and os.sep not in file and file in shipped_sets():
            resource = resources.files(SHIPPED_SETS) / f"{file}.toml"
            return resource.read_text(encoding="utf-8"), f"{file} (shipped)"
        with open(file, "rb") as stream:
            return read_bounded(stream, file), file
    except TomlFileError as exc:
        raise CliError(str(exc), ExitCode.BAD_INPUT) from None
    except OSError as exc:
        known = ", ".join(shipped_sets())
        raise CliError(f"{file}: cannot read: {exc.strerror or exc} (shipped sets: {known})",
                       ExitCode.BAD_INPUT) from None


def _file_names(ctx: click.Context, param: click.Parameter, incomplete: str
                ) -> list[CompletionItem]:
    """Completion for ``param load``: the files here (the shell completes paths) and the
    parameter sets shipped with the package."""
    from click.shell_completion import CompletionItem

    shipped = [CompletionItem(n) for n in shipped_sets() if n.startswith(incomplete)]
    return [*shipped, CompletionItem(incomplete, type="file")]


@param.command("load", epilog=EXIT_CODES_HELP)
@click.argument("file", shell_complete=_file_names)
@format_option
@connection_options()
def load(file: str, fmt: str, conn: ConnectionOptions) -> int:
    """Set every parameter in a TOML FILE ('-' for stdin, or the name of a shipped set such
    as seed-high), one at a time; each line is reported as confirmed or failed. All values
    are checked before the first is sent."""
    text, source = _read_settings(file)
    entries = parse_param_file(text, source)
    if not entries:
        raise CliError(f"{source}: no parameters in the file", ExitCode.BAD_INPUT)
    conn.note_ephemeral()
    return run(_load(conn, entries, fmt), conn.single.url)


LOAD_COLUMNS = (Column("status", "status"), Column("name", "name"),
                Column("requested", "requested"), Column("confirmed", "confirmed"),
                Column("error", "error"))


async def _load(conn: ConnectionOptions, entries: list[Setting], fmt: str) -> int:
    worst = ExitCode.OK
    async with conn.link(conn.single) as link:
        results = await link.sync_params(
            [(p.full_name(code), None, value) for p, code, value in entries]
        )
    by_name = {p.full_name(code): p for p, code, _ in entries}
    rows: list[dict[str, Any]] = []
    for result in results:
        p = by_name[result.name]
        if result.ok:
            assert result.confirmed is not None
            rows.append({"status": "ok", "name": result.name,
                         "requested": number(result.requested, p.type),
                         "confirmed": number(result.confirmed, p.type), "error": None})
            if fmt == "table":
                echo_out(f"ok      {result.name} = {format_value(result.confirmed, p.type)}")
            continue
        assert result.error is not None
        error = classify(result.error, conn.single.url)
        rows.append({"status": "failed", "name": result.name,
                     "requested": number(result.requested, p.type), "confirmed": None,
                     "error": error.format_message()})
        if fmt == "table":
            echo_out(f"failed  {result.name} = {format_value(result.requested, p.type)}: "
                     f"{error.format_message()}")
        worst = max(worst, ExitCode(error.exit_code))
    if fmt != "table":
        emit_rows(fmt, LOAD_COLUMNS, rows)
    ok = sum(r.ok for r in results)
    if worst is not ExitCode.OK:
        raise CliError(f"{len(results) - ok} of {len(results)} parameters failed", worst)
    return ExitCode.OK


def write_output(file: str, text: str, *, force: bool) -> None:
    """Write ``text`` to FILE as every file a command writes (:mod:`fpgalink.cli.files`): a
    new file via ``FILE.partial``, renamed into place (a reader never sees half a file); an
    existing one only with ``force``, a symlink's target replaced that way and the link kept;
    a device or FIFO is written as a stream. One-line error otherwise."""
    target = Path(file)
    try:
        mode = target.stat().st_mode if target.exists() else None
        if mode is not None and stat.S_ISDIR(mode):
            raise CliError(f"{file}: is a directory", ExitCode.BAD_INPUT)
        if mode is not None and not stat.S_ISREG(mode):
            with open(target, "w", encoding="utf-8") as stream:
                stream.write(text)
            return
    except OSError as exc:
        raise CliError(f"{file}: cannot write: {exc.strerror or exc}", ExitCode.FAILURE) from None
    write_file(target, text.encode("utf-8"), force=force)
    if mode is not None:
        with contextlib.suppress(OSError):  # the replaced file's permissions
            os.chmod(target.resolve(), stat.S_IMODE(mode))


@param.command("dump", epilog=EXIT_CODES_HELP)
@click.argument("file", type=click.Path(dir_okay=False, allow_dash=True))
@force_option
@connection_options()
def dump(file: str, force: bool, conn: ConnectionOptions) -> int:
    """Read every parameter from the board into a TOML FILE ('-' for stdout) that `param
    load` and `fpgaemu serve --config` accept. Nothing is written unless every value was
    read; an existing regular file is refused unless --force (then replaced whole), a
    device or FIFO written to."""
    target = Path(file)
    if file != "-" and not (target.exists() and not target.is_dir()
                            and not stat.S_ISREG(target.stat().st_mode)):
        check_output(target, force=force)  # before the board is read
    board = run(_read(conn), conn.single.url)
    values = board.values
    stamp = dt.datetime.now(dt.UTC).replace(microsecond=0).isoformat()
    # The header says whose parameters these are: a file read from one firmware, loaded
    # into another, is where a changed declaration bites.
    text = render_parameter_file(values, f"fpgalink parameters read from {conn.single.url} "
                                         f"at {stamp}; board: {board.identity}")
    if file == "-":
        write_out(text)
        return ExitCode.OK
    write_output(file, text, force=force)
    note(f"wrote {len(values)} values to {file}")
    return ExitCode.OK
