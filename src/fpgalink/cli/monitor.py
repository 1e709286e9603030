"""``monitor``: a live table of one or two boards, or a CSV/JSON-lines stream for pipes."""

from __future__ import annotations

import asyncio
import contextlib
import csv
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import click
from rich.console import Console, Group
from rich.live import Live
from rich.table import Table

from fpgalink.aio.link import Link, LinkState
from fpgalink.catalogue import ChannelTelemetry
from fpgalink.cli._common import (
    EXIT_CODES_HELP,
    ConnectionOptions,
    Endpoint,
    ExitCode,
    connection_options,
    install_stop_signals,
    quiet_stdout,
    run,
    stop_exit_code,
    wait_or_stop,
)
from fpgalink.cli._telemetry import TELEMETRY_FIELDS, BoardClock, Streaming, telemetry_row

__all__ = ["BoardSession", "monitor", "open_sessions"]

REFRESH_S = 0.1  #: table refresh; also how often the TM rate is re-estimated


def compact(value: Any) -> Any:
    """Floats from the wire are float32: 7 significant digits say all they hold."""
    if isinstance(value, float):
        return float(f"{value:.7g}")
    return value


def flag_letters(channel: ChannelTelemetry) -> str:
    return "".join(letter if on else "-" for letter, on in
                   (("E", channel.enabled), ("S", channel.end_stop), ("X", channel.saturated)))


@dataclass
class BoardSession:
    """One board being watched: its link, streaming switch, clock and rate estimate."""

    endpoint: Endpoint
    link: Link
    streaming: Streaming
    clock: BoardClock = field(default_factory=BoardClock)
    rate: float = 0.0
    _rate_mark: tuple[float, int] | None = None

    def update_rate(self, now: float) -> None:
        received = self.link.stats.telemetry_received
        if self._rate_mark is not None:
            then, count = self._rate_mark
            if now - then >= 0.5:
                self.rate = (received - count) / (now - then)
                self._rate_mark = (now, received)
        else:
            self._rate_mark = (now, received)

    @property
    def status(self) -> str:
        if self.link.state is LinkState.RECONNECTING:
            return "port lost, reconnecting"
        if self.link.board_alive:
            return "alive"
        return "waiting" if self.link.stats.messages_received == 0 else "SILENT"


async def open_sessions(stack: contextlib.AsyncExitStack, conn: ConnectionOptions
                        ) -> list[BoardSession]:
    """Open every board's link (closed by ``stack``). Long-running commands keep reconnecting
    after a lost port and use the library's liveness timeout, so the table shows the truth."""
    sessions = []
    for endpoint in conn.endpoints:
        link = conn.link(endpoint, reconnect=True, liveness_timeout=0.7, name=endpoint.name)
        await stack.enter_async_context(link)
        sessions.append(BoardSession(endpoint, link, Streaming(link)))
    return sessions


async def start_streaming(sessions: list[BoardSession], passive: bool) -> None:
    if passive:
        return
    for session in sessions:
        await session.streaming.start()


async def restore_streaming(sessions: list[BoardSession], passive: bool) -> None:
    if passive:
        return
    for session in sessions:
        await session.streaming.restore()


def render(sessions: list[BoardSession], started: float, duration: float | None) -> Group:
    telemetry = Table(title="Telemetry", title_justify="left")
    for column in ("board", "ch", "position", "speed deg/s", "current A", "pwm", "ref",
                   "flags"):
        telemetry.add_column(column, justify="left" if column in ("board", "ch") else "right")
    link = Table(title="Link", title_justify="left")
    for column in ("board", "port", "board status", "TM/s", "lost", "errors", "retries",
                   "heartbeats (E)"):
        link.add_column(column, justify="left" if column in ("board", "port", "board status")
                        else "right")
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
@click.option("--duration", type=click.FloatRange(min=0, min_open=True),
              help="Stop after S seconds (default: until Ctrl-C).")
@click.option("--format", "fmt", type=click.Choice(["table", "csv", "jsonl"]),
              help="table (live view), or csv / jsonl with one line per TM sample. "
                   "Default: table on a terminal, csv when piped.")
@click.option("--passive", is_flag=True,
              help="Only listen: do not turn GetDataPeriodical on (and back off).")
@connection_options(multi=True)
def monitor(duration: float | None, fmt: str | None, passive: bool,
            conn: ConnectionOptions) -> int:
    """Watch telemetry of both channels and the link's health, live.

    Turns telemetry on (GetDataPeriodical = 1) while it runs and restores the previous value
    when it stops. Link events (board lost/found, port lost) go to stderr in stream formats.
    """
    fmt = fmt or ("table" if sys.stdout.isatty() else "csv")
    code = run(_monitor(conn, duration, fmt, passive))
    return code


async def _monitor(conn: ConnectionOptions, duration: float | None, fmt: str,
                   passive: bool) -> int:
    stop = asyncio.Event()
    install_stop_signals(stop)
    pipe_closed = False
    async with contextlib.AsyncExitStack() as stack:
        sessions = await open_sessions(stack, conn)
        subs = [s.link.telemetry(maxsize=65536) for s in sessions]
        tasks: list[asyncio.Task[None]] = []
        for session in sessions:
            tasks.append(asyncio.ensure_future(_report_events(session)))
        try:
            await start_streaming(sessions, passive)
            if fmt == "table":
                await _live_table(sessions, stop, duration)
            else:
                write = _stream_writer(fmt)
                for session, sub in zip(sessions, subs, strict=True):
                    tasks.append(asyncio.ensure_future(_stream(session, sub, write, stop)))
                await wait_or_stop(stop, duration)
                pipe_closed = getattr(stop, "pipe_closed", False)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await restore_streaming(sessions, passive)
    if pipe_closed:
        quiet_stdout()
        return ExitCode.OK
    return stop_exit_code(stop)


async def _live_table(sessions: list[BoardSession], stop: asyncio.Event,
                      duration: float | None) -> None:
    started = time.monotonic()
    deadline = None if duration is None else started + duration
    with Live(render(sessions, started, duration), console=Console(), auto_refresh=False,
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
            sys.stdout.write(json.dumps(row, separators=(",", ":")) + "\n")

        return write_json
    writer = csv.DictWriter(sys.stdout, fieldnames=["board", *TELEMETRY_FIELDS],
                            lineterminator="\n")
    writer.writeheader()
    return writer.writerow


async def _stream(session: BoardSession, sub: Any, write: Callable[[dict[str, Any]], None],
                  stop: asyncio.Event) -> None:
    name = session.endpoint.name
    try:
        async for sample in sub:
            row = {"board": name, **{k: compact(v) for k, v in
                                     telemetry_row(sample, 0.0).items()}}
            row["timestamp"] = round(session.clock.seconds(sample.t_us), 6)
            write(row)
            if len(sub) == 0:  # flush per burst, not per line
                sys.stdout.flush()
    except BrokenPipeError:
        stop.pipe_closed = True  # type: ignore[attr-defined]
        stop.set()


async def _report_events(session: BoardSession) -> None:
    async for event in session.link.watch():
        detail = f": {event.detail}" if event.detail else ""
        click.echo(f"# {session.endpoint.name}: {event.kind.value}{detail}", err=True)
