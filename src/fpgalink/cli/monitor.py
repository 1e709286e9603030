"""``monitor``: a live table of one or two boards, or a CSV/JSON-lines stream for pipes."""

from __future__ import annotations

import asyncio
import contextlib
import csv
import io
import json
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import click

from fpgalink.aio.link import Subscription
from fpgalink.cli.liveview import add_live_boards, foxglove_option, opened_live
from fpgalink.cli.options import ConnectionOptions, connection_options
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, FiniteRange, quiet_stdout
from fpgalink.cli.session import (
    TELEMETRY_FIELDS,
    BoardSession,
    check_boards_answered,
    compact,
    flag_letters,
    install_stop_signals,
    json_safe,
    open_sessions,
    restore_streaming,
    run,
    start_streaming,
    stop_exit_code,
    telemetry_row,
    wait_or_stop,
    write_stdout,
)
from fpgalink.protocol import Telemetry

if TYPE_CHECKING:  # rich loads when the table is drawn
    from rich.console import Group

    from fpgalink.live import LiveAddress

__all__ = ["monitor"]

REFRESH_S = 0.1  #: table refresh; also how often the TM rate is re-estimated
TABLE_READ_LATENCY_S = 0.01


def render(sessions: list[BoardSession], started: float, duration: float | None) -> Group:
    from rich.console import Group
    from rich.table import Table

    telemetry = Table(title="Telemetry", title_justify="left")
    for column in ("board", "ch", "position", "speed deg/s", "current A", "pwm", "ref",
                   "flags"):
        telemetry.add_column(column, justify="left" if column in ("board", "ch") else "right",
                             overflow="fold")
    # Nothing is cut with an ellipsis in a narrow terminal: a long port folds onto a second
    # line rather than two boards' ports reading the same ("/tmp/fpga…" twice).
    link = Table(title="Link", title_justify="left")
    for column in ("board", "port", "board status", "TM/s", "lost", "errors", "retries",
                   "heartbeats (E)"):
        link.add_column(column, justify="left" if column in ("board", "port", "board status")
                        else "right", overflow="fold")
    for session in sessions:
        sample = session.link.latest
        for label in ("A", "B"):
            if sample is None:
                telemetry.add_row(session.endpoint.name, label, *["—"] * 6)
                continue
            ch = sample.a if label == "A" else sample.b
            telemetry.add_row(session.endpoint.name, label, str(ch.position),
                              f"{ch.speed:.2f}", f"{ch.current:.3f}", str(ch.pwm),
                              f"{ch.reference:.2f}", flag_letters(ch))
        stats = session.link.stats
        link.add_row(session.endpoint.name, session.endpoint.url, session.status,
                     f"{session.rate:.0f}", str(stats.lost), str(stats.decode_errors),
                     str(stats.retries), str(stats.alive_received))
    elapsed = time.monotonic() - started
    until = f" of {duration:g}" if duration is not None else ""
    footer = Table.grid()
    footer.add_row(f"{elapsed:.1f}{until} s — flags: E enable, S end-stop, X saturated — "
                   "Ctrl-C stops")
    return Group(telemetry, link, footer)


@click.command(epilog=EXIT_CODES_HELP)
@click.option("--duration", type=FiniteRange(min=0, min_open=True),
              help="Stop after S seconds (default: until Ctrl-C).")
@click.option("--format", "fmt", type=click.Choice(["table", "csv", "jsonl"]),
              help="table (live view), or csv / jsonl with one line per TM sample. "
                   "Default: table on a terminal, csv when piped.")
@click.option("--passive", is_flag=True,
              help="Only listen: do not turn GetDataPeriodical on (and back off).")
@foxglove_option
@connection_options(multi=True)
def monitor(duration: float | None, fmt: str | None, passive: bool,
            foxglove: LiveAddress | None, conn: ConnectionOptions) -> int:
    """Watch telemetry of both channels and the link's health, live.

    Turns telemetry on (GetDataPeriodical = 1) while it runs and restores the previous value
    when it stops. Link events (board lost/found, port lost) go to stderr in stream formats.
    """
    fmt = fmt or ("table" if sys.stdout.isatty() else "csv")
    code = run(_monitor(conn, duration, fmt, passive, foxglove))
    return code


async def _monitor(conn: ConnectionOptions, duration: float | None, fmt: str,
                   passive: bool, foxglove: LiveAddress | None = None) -> int:
    stop = asyncio.Event()
    install_stop_signals(stop)
    failure: list[BaseException] = []
    pipe_closed = False
    started = time.time()
    async with contextlib.AsyncExitStack() as stack:
        sessions = await open_sessions(stack, conn, passive=passive)
        view = await stack.enter_async_context(opened_live(foxglove, "fpgalink-cli monitor"))
        add_live_boards(view, {s.endpoint.name: s.link for s in sessions})
        subs = [s.link.telemetry(maxsize=65536) for s in sessions]
        tasks: list[asyncio.Task[None]] = []
        for session in sessions:
            report = _report_event(session) if fmt != "table" else None
            tasks.append(asyncio.ensure_future(session.follow(report)))
        try:
            await start_streaming(sessions, passive)
            if fmt == "table":
                # A 10 Hz view need not wake for every sample: reads are gathered for
                # 10 ms at a time (nothing is lost; requests are not held back).
                for session in sessions:
                    session.link.set_read_latency(TABLE_READ_LATENCY_S)
                await _live_table(sessions, stop, duration)
            else:
                write = _stream_writer(fmt)
                for session, sub in zip(sessions, subs, strict=True):
                    tasks.append(asyncio.ensure_future(
                        _stream(session, sub, write, stop, failure)))
                await wait_or_stop(stop, duration)
                pipe_closed = getattr(stop, "pipe_closed", False)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await restore_streaming(sessions, passive)
    if failure:
        raise failure[0]
    if pipe_closed:
        quiet_stdout()
        return ExitCode.OK
    check_boards_answered(sessions, started)
    return stop_exit_code(stop)


async def _live_table(sessions: list[BoardSession], stop: asyncio.Event,
                      duration: float | None) -> None:
    from rich.live import Live

    from fpgalink.cli.output import console

    started = time.monotonic()
    deadline = None if duration is None else started + duration
    with Live(render(sessions, started, duration), console=console(), auto_refresh=False,
              transient=False) as live:
        while not stop.is_set():
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            for session in sessions:
                session.update_rate(now)
            live.update(render(sessions, started, duration), refresh=True)
            wait = REFRESH_S if deadline is None else min(REFRESH_S, max(0.0, deadline - now))
            await wait_or_stop(stop, wait)
        live.update(render(sessions, started, duration), refresh=True)


def _stream_writer(fmt: str) -> Callable[[dict[str, Any]], None]:
    if fmt == "jsonl":
        def write_json(row: dict[str, Any]) -> None:
            write_stdout(json.dumps(json_safe(row), separators=(",", ":"), allow_nan=False)
                         + "\n")

        return write_json
    stream = io.StringIO()
    writer = csv.DictWriter(stream, fieldnames=["board", *TELEMETRY_FIELDS],
                            lineterminator="\n")

    def write_csv(row: dict[str, Any]) -> None:
        writer.writerow(row)
        write_stdout(stream.getvalue())
        stream.seek(0)
        stream.truncate()

    writer.writeheader()
    write_stdout(stream.getvalue())
    stream.seek(0)
    stream.truncate()
    return write_csv


async def _stream(session: BoardSession, sub: Subscription[Telemetry],
                  write: Callable[[dict[str, Any]], None], stop: asyncio.Event,
                  failure: list[BaseException]) -> None:
    name = session.endpoint.name
    try:
        async for sample in sub:
            row = {"board": name, **{k: compact(v) for k, v in
                                     telemetry_row(sample, 0.0).items()}}
            row["timestamp"] = round(session.clock.seconds(sample.t_us, time.time()), 6)
            write(row)
            if len(sub) == 0:  # flush per burst, not per line
                sys.stdout.flush()
    except BrokenPipeError:
        stop.pipe_closed = True  # type: ignore[attr-defined]
        stop.set()
    except (CliError, OSError) as exc:  # stdout on a full disk, say
        failure.append(exc if isinstance(exc, CliError) else
                       CliError(f"cannot write to stdout: {exc.strerror or exc}",
                                ExitCode.FAILURE))
        stop.set()


def _report_event(session: BoardSession) -> Callable[[str, str, float], None]:
    def report(kind: str, detail: str, at: float) -> None:
        text = f": {detail}" if detail else ""
        click.echo(f"# {session.endpoint.name}: {kind}{text}", err=True)

    return report
