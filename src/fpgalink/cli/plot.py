"""``plot``: fields of a recording against time, saved as a PNG (or SVG, PDF) — for a quick
look without Foxglove or PlotJuggler at hand.

Reads the MCAP files ``record`` writes (and any MCAP with JSON messages). A recording whose
writer was killed has no summary; its complete chunks are still read, in file order, and the
command says so."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import click

from fpgalink.cli.figures import check_plot_path, new_figure, save_figure
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, note

__all__ = ["Reading", "Series", "field_value", "plot", "read_series"]

DEFAULT_FIELDS = "a.speed+a.ref,b.speed+b.ref"
TELEMETRY_SUFFIX = "/telemetry"
#: What mcap's readers raise on a torn or foreign file (it does not wrap its struct and
#: decoding errors in McapError).
_UNREADABLE = (Exception,)
_CLOCKS = {
    "publish": "the board's sample time (publish_time)",
    "log": "host receive time (log_time)",
}


@dataclass
class Series:
    """One field of one topic: time (s since the recording's first message) and values."""

    topic: str
    field: str
    t: list[float] = dataclasses.field(default_factory=list)
    values: list[float] = dataclasses.field(default_factory=list)


def field_value(record: Any, path: str) -> float | None:
    """``path`` in a JSON record: ``a.speed`` is ``record["a"]["speed"]`` when nested, else
    the flat ``a_speed`` our telemetry uses. ``None`` when absent or not a number (a JSON
    ``null`` — a non-finite value on the wire — included)."""
    node: Any = record
    for part in path.split("."):
        if isinstance(node, dict) and part in node:
            node = node[part]
        else:
            node = None
            break
    if node is None and isinstance(record, dict):
        node = record.get(path.replace(".", "_"))
    if isinstance(node, bool) or not isinstance(node, int | float):
        return None
    return float(node)


def _messages(stream: IO[bytes], topics: list[str] | None) -> tuple[Iterator[Any], bool]:
    """Messages of ``topics`` (all when ``None``), and whether the file was complete."""
    from mcap.reader import NonSeekingReader, make_reader

    try:
        reader = make_reader(stream)
        if reader.get_summary() is not None:
            return reader.iter_messages(topics=topics), True
    except _UNREADABLE:
        pass
    stream.seek(0)
    # In file order: sorting would load the whole file to memory; time is sorted below.
    return NonSeekingReader(stream).iter_messages(topics=topics, log_time_order=False), False


@dataclass
class Reading:
    """What :func:`read_series` found: the series, whether the file was complete, and how
    many messages of the chosen topics were skipped because they could not be read as a
    JSON record (not JSON, nested too deeply, a number beyond any float …)."""

    series: list[Series]
    complete: bool
    skipped: int = 0


def _values(data: bytes, fields: list[str]) -> list[tuple[str, float]]:
    """The finite values of ``fields`` in one message; ``ValueError`` when the message is
    not a JSON record whose numbers are floats."""
    try:
        record = json.loads(data)
        values = [(name, field_value(record, name)) for name in fields]
    except (ValueError, UnicodeDecodeError, RecursionError, OverflowError) as exc:
        raise ValueError(str(exc)) from None
    return [(name, v) for name, v in values if v is not None and math.isfinite(v)]


def read_series(path: Path, topics: list[str] | None, fields: list[str],
                clock: str = "publish") -> Reading:
    """Each (topic, field) pair as a time series, whether the file was complete, and the
    messages skipped. ``topics=None``: every ``/board/NAME/telemetry`` topic in the file."""
    series: dict[tuple[str, str], Series] = {}
    if topics is not None:
        series = {(t, f): Series(t, f) for t in topics for f in fields}
    origin: float | None = None
    complete = False
    skipped = 0
    try:
        with path.open("rb") as stream:
            messages, complete = _messages(stream, topics)
            for _schema, channel, message in messages:
                topic = channel.topic
                if topics is None and not topic.endswith(TELEMETRY_SUFFIX):
                    continue
                try:
                    values = _values(message.data, fields)
                except ValueError:
                    skipped += 1  # one bad message: said, and the rest still plotted
                    continue
                stamp = (message.publish_time if clock == "publish" else message.log_time) / 1e9
                origin = stamp if origin is None else min(origin, stamp)
                for name, value in values:
                    line = series.get((topic, name)) or series.setdefault(
                        (topic, name), Series(topic, name))
                    line.t.append(stamp)
                    line.values.append(value)
    except OSError as exc:
        raise CliError(f"{path}: cannot read: {exc.strerror or exc}", ExitCode.FAILURE) from None
    except _UNREADABLE as exc:
        if origin is None:
            why = "it ends before its first complete chunk" if type(exc).__name__ == \
                "EndOfFile" else f"{type(exc).__name__}: {exc}"
            raise CliError(f"{path}: not a readable MCAP file ({why})",
                           ExitCode.BAD_INPUT) from None
        complete = False  # a torn end after good chunks: plot what came before it
    for line in series.values():
        order = sorted(range(len(line.t)), key=line.t.__getitem__)
        line.t = [line.t[i] - (origin or 0.0) for i in order]
        line.values = [line.values[i] for i in order]
    return Reading(sorted(series.values(), key=lambda s: (s.topic, fields.index(s.field))),
                   complete, skipped)


@click.command(epilog=EXIT_CODES_HELP)
@click.argument("recording", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--topic", "topics", multiple=True, metavar="TOPIC",
              help="Topic to plot (repeatable). Default: every /board/NAME/telemetry.")
@click.option("--fields", default=DEFAULT_FIELDS, show_default=True, metavar="F1,F2+F3,…",
              help="Fields to plot, one panel each; F2+F3 share a panel. A field is a.speed "
                   "or a_speed; nested JSON as a.b.c.")
@click.option("--time", "clock", type=click.Choice(sorted(_CLOCKS)), default="publish",
              show_default=True,
              help="Time axis: the board's sample time (publish) or host receive time (log).")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="Image to write (.png, .svg or .pdf). Default: RECORDING with .png.")
def plot(recording: Path, topics: tuple[str, ...], fields: str, clock: str,
         output: Path | None) -> int:
    """Plot fields of a recording against time into a PNG.

    One panel per field (or per group joined with +), one line per topic and field. Values
    the recording holds as null (non-finite on the wire) are gaps. Needs matplotlib
    (pip install 'fpgalink[plot]').
    """
    panels = [[f.strip() for f in group.split("+") if f.strip()] for group in fields.split(",")]
    panels = [p for p in panels if p]
    names = list(dict.fromkeys(f for panel in panels for f in panel))
    if not names:
        raise CliError("--fields: give at least one field name", ExitCode.BAD_INPUT)
    output = output or recording.with_suffix(".png")
    check_plot_path(output, "--output")
    reading = read_series(recording, list(topics) or None, names, clock)
    series = reading.series
    if not reading.complete:
        note(f"{recording} was not closed (no summary): plotting the complete chunks it holds")
    if reading.skipped:
        note(f"skipped {reading.skipped} message(s) that are not JSON records with plottable "
             "numbers (not JSON, nested too deeply, or a number beyond a float's range)")
    chosen = sorted({s.topic for s in series})
    if not chosen:
        where = ", ".join(topics) if topics else "any /board/NAME/telemetry topic"
        raise CliError(f"{recording}: no values for {', '.join(names)} on {where}",
                       ExitCode.BAD_INPUT)
    empty = [n for n in names if not any(s.values for s in series if s.field == n)]
    if len(empty) == len(names):
        raise CliError(f"{recording}: no values for {', '.join(names)} on "
                       f"{', '.join(chosen)}", ExitCode.BAD_INPUT)
    if empty:
        note(f"no values for {', '.join(empty)}: left out")
    shown = [[n for n in panel if n not in empty] for panel in panels]
    shown = [panel for panel in shown if panel]
    figure = new_figure((9, 2.2 * len(shown) + 0.8))
    axes = figure.subplots(len(shown), 1, sharex=True, squeeze=False)[:, 0]
    for ax, panel in zip(axes, shown, strict=True):
        for line in series:
            if line.field in panel and line.values:
                label = line.field if len(chosen) == 1 else f"{line.topic} {line.field}"
                ax.plot(line.t, line.values, label=label, linewidth=1)
        ax.set_ylabel(" / ".join(panel))
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize="small")
    title = recording.name if len(chosen) > 1 else f"{recording.name}: {chosen[0]}"
    axes[0].set_title(title)
    axes[-1].set_xlabel(f"s since the first message, {_CLOCKS[clock]}")
    save_figure(figure, output)
    points = sum(len(s.values) for s in series)
    note(f"plotted {points} points of {len(names) - len(empty)} field(s) from "
         f"{len(chosen)} topic(s) to {output}")
    return ExitCode.OK
