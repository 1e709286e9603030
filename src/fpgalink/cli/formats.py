"""One output contract for every command that prints data (docs/cli.md, "Output formats"):

* ``--format table`` (the default) is for people: a table that fits the terminal. When it
  would not, columns are left out by priority (and the caption says which), never a name
  cut short into another's: the columns that tell rows apart are never dropped or
  truncated, they fold onto a second line if they must.
* ``--format json`` is one JSON document on stdout (an object, or an array — ``[]`` when
  there is nothing), numbers as numbers with the unit in the key (``timeout_s``,
  ``rise_time_s``), ``null`` for a value that is absent or not finite.
* ``--format csv`` has a header line and one line per row, with the JSON keys as headers.

A write error on stdout (``> /dev/full``) is one line and exit 1 (:func:`write_out`)."""

from __future__ import annotations

import csv
import io
import json
import math
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

import click

from fpgalink.cli.output import console, stdout_errors, write_out

if TYPE_CHECKING:
    from rich.console import Console
    from rich.table import Table

__all__ = [
    "FORMATS",
    "Column",
    "console_width",
    "emit_document",
    "emit_rows",
    "fit_table",
    "format_option",
    "json_value",
    "print_renderable",
    "table_width",
    "write_out",
]

T = TypeVar("T")

FORMATS = ("table", "json", "csv")
#: Width of a table written into a pipe or file when ``COLUMNS`` does not say otherwise:
#: wide enough that a script reading it gets every column.
PIPE_WIDTH = 200


def format_option(func: Callable[..., T]) -> Callable[..., T]:
    """``--format table|json|csv``; the command receives ``fmt``."""
    return click.option(
        "--format", "fmt", type=click.Choice(FORMATS), default="table", show_default=True,
        help="table for people; json (one document, numbers as numbers, units in the keys) "
             "or csv (a header, then one line per row) for scripts.")(func)


def json_value(value: Any) -> Any:
    """A value as JSON has it: non-finite floats are ``null`` (JSON has no NaN)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_value(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_value(v) for v in value]
    return value


def emit_document(document: Any) -> None:
    """One JSON document on stdout."""
    write_out(json.dumps(json_value(document), indent=2, ensure_ascii=False, allow_nan=False)
              + "\n")


@dataclass(frozen=True, slots=True)
class Column:
    """One column of a command's rows."""

    key: str  #: the JSON key and CSV header: snake_case with the unit (``rise_time_s``)
    header: str  #: the table's header
    #: Table text of a value (default: ``str``, ``""`` for ``None``).
    render: Callable[[Any], str] | None = None
    justify: str = "left"
    #: 0: never left out (it tells rows apart, or it is the data); otherwise columns with
    #: higher numbers are left out first when the table does not fit.
    drop: int = 0

    def text(self, value: Any) -> str:
        if self.render is not None:
            return self.render(value)
        return "" if value is None else str(value)


def console_width() -> int:
    """The terminal's width; ``COLUMNS`` when set; else :data:`PIPE_WIDTH` in a pipe."""
    columns = os.environ.get("COLUMNS", "")
    if columns.isdigit() and int(columns) > 0:
        return int(columns)
    try:
        if sys.stdout.isatty():
            return os.get_terminal_size(sys.stdout.fileno()).columns
    except (OSError, ValueError):
        pass
    return PIPE_WIDTH


def _console() -> Console:
    return console(width=console_width(), soft_wrap=False)


def print_renderable(renderable: Any) -> None:
    """A rich renderable on stdout, with a write error as one line (exit 1)."""
    console = _console()
    with stdout_errors():
        console.print(renderable)
        console.file.flush()


def table_width(widths: Sequence[int]) -> int:
    """What a rich table with the default box and padding takes: each column its text, a
    space either side and a rule; one more rule at the end."""
    return sum(w + 3 for w in widths) + 1


def fit_table(columns: Sequence[Column], rows: Sequence[Sequence[str]], width: int,
              title: str | None = None) -> Table:
    """A rich table of ``rows`` (text) that fits ``width``: droppable columns are left out,
    highest :attr:`Column.drop` first, until it fits; what is left folds rather than being
    cut with an ellipsis. Every text is literal (:class:`rich.text.Text`): a cell holds what
    a user or a dependency wrote, never markup."""
    from rich.table import Table
    from rich.text import Text

    natural = [max([len(c.header), *(len(r[i]) for r in rows)]) for i, c in
               enumerate(columns)]
    keep = list(range(len(columns)))
    droppable = sorted((i for i, c in enumerate(columns) if c.drop),
                       key=lambda i: (-columns[i].drop, -i))
    left_out: list[str] = []
    for index in droppable:
        if table_width([natural[i] for i in keep]) <= width:
            break
        keep.remove(index)
        left_out.append(columns[index].header)
    caption = None
    if left_out:
        caption = (f"left out to fit {width} columns: {', '.join(left_out)} "
                   "(--format json has every column)")
    table = Table(title=None if title is None else Text(title),
                  caption=None if caption is None else Text(caption), title_justify="left",
                  caption_justify="left")
    for i in keep:
        column = columns[i]
        table.add_column(Text(column.header), justify=column.justify,  # type: ignore[arg-type]
                         overflow="fold")
    for row in rows:
        table.add_row(*(Text(row[i]) for i in keep))
    return table


def _csv_cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):  # a set of values in one cell: space-separated
        return " ".join(str(_csv_cell(v)) for v in value)
    return value


def emit_rows(fmt: str, columns: Sequence[Column], rows: Sequence[dict[str, Any]], *,
              title: str | None = None, document: Any = None) -> None:
    """Rows of data in ``fmt``. JSON is the list of rows, or ``document`` when the command
    has more to say than rows (a summary around them)."""
    if fmt == "json":
        emit_document([{c.key: row.get(c.key) for c in columns} for row in rows]
                      if document is None else document)
    elif fmt == "csv":
        stream = io.StringIO()
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow([c.key for c in columns])
        for row in rows:
            writer.writerow([_csv_cell(row.get(c.key)) for c in columns])
        write_out(stream.getvalue())
    else:
        text_rows = [[c.text(row.get(c.key)) for c in columns] for row in rows]
        print_renderable(fit_table(columns, text_rows, console_width(), title))
