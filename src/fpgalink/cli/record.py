"""``record``: telemetry, parameter changes, link events and link statistics into MCAP
(JSON Schema + JSON, so Foxglove and PlotJuggler plot it as is) or telemetry into CSV."""

from __future__ import annotations

import asyncio
import contextlib
import csv
import json
import time
from pathlib import Path
from typing import IO, Any, Protocol

import click
from mcap.writer import Writer
from rich.console import Console
from rich.progress import (
    BarColumn,
    Progress,
    SpinnerColumn,
    TextColumn,
    TimeElapsedColumn,
)

from fpgalink import __version__
from fpgalink.cli.options import ConnectionOptions, connection_options
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode
from fpgalink.cli.session import (
    TELEMETRY_FIELDS,
    BoardSession,
    compact,
    install_stop_signals,
    on_messages,
    open_sessions,
    restore_streaming,
    run,
    start_streaming,
    stop_exit_code,
    telemetry_row,
    telemetry_schema,
    wait_or_stop,
)
from fpgalink.errors import UnknownParameter
from fpgalink.protocol import ParamAck, ParamNack, Parsed, lookup

__all__ = ["CsvSink", "McapSink", "record"]

STATS_PERIOD_S = 1.0
CHUNK_BYTES = 64 * 1024

PARAM_SCHEMA: dict[str, Any] = {
    "title": "fpgalink.ParameterChange", "type": "object",
    "properties": {
        "timestamp": {"type": "number", "description": "host epoch time, s"},
        "name": {"type": "string", "description": "e.g. Kp_Wheel_PidA"},
        "param_id": {"type": "integer"},
        "channel": {"type": "integer", "description": "0 board, 1 A, 2 B"},
        "value": {"type": "number", "description": "value in force (PA); absent if refused"},
        "status": {"type": "string", "enum": ["in_force", "refused"]},
        "detail": {"type": "string"},
    },
}
EVENT_SCHEMA: dict[str, Any] = {
    "title": "fpgalink.LinkEvent", "type": "object",
    "properties": {
        "timestamp": {"type": "number", "description": "host epoch time, s"},
        "kind": {"type": "string"},
        "detail": {"type": "string"},
    },
}
STATS_FIELDS = ("telemetry_rate", "telemetry_received", "lost", "decode_errors", "malformed",
                "retries", "heartbeat_misses", "alive_received", "subscriber_drops",
                "port_losses", "reconnects")
STATS_SCHEMA: dict[str, Any] = {
    "title": "fpgalink.LinkStats", "type": "object",
    "properties": {"timestamp": {"type": "number"},
                   **{name: {"type": "number"} for name in STATS_FIELDS}},
}


class Sink(Protocol):
    def telemetry(self, board: str, row: dict[str, Any]) -> None: ...
    def parameter(self, board: str, record: dict[str, Any]) -> None: ...
    def event(self, board: str, record: dict[str, Any]) -> None: ...
    def stats(self, board: str, record: dict[str, Any]) -> None: ...
    def close(self) -> None: ...


class McapSink:
    """Topics per board: ``/board/<name>/telemetry``, ``/params``, ``/events``, ``/stats``."""

    def __init__(self, path: Path, boards: list[str], metadata: dict[str, str]) -> None:
        self._file: IO[bytes] = path.open("wb")
        # Small chunks: a hard kill (no Ctrl-C) loses at most ~a second of telemetry.
        self._writer = Writer(self._file, chunk_size=CHUNK_BYTES)
        self._writer.start(profile="", library=f"fpgalink-cli {__version__}")
        schemas = {
            kind: self._writer.register_schema(
                name=schema["title"], encoding="jsonschema",
                data=json.dumps(schema).encode())
            for kind, schema in (("telemetry", telemetry_schema()), ("params", PARAM_SCHEMA),
                                 ("events", EVENT_SCHEMA), ("stats", STATS_SCHEMA))
        }
        self._channels = {
            (board, kind): self._writer.register_channel(
                topic=f"/board/{board}/{kind}", message_encoding="json", schema_id=schema_id)
            for board in boards for kind, schema_id in schemas.items()
        }
        self._sequence = 0
        self._writer.add_metadata("fpgalink", metadata)
        self.messages = 0

    def _add(self, board: str, kind: str, record: dict[str, Any]) -> None:
        stamp = int(record["timestamp"] * 1e9)
        self._sequence += 1
        self._writer.add_message(self._channels[(board, kind)], log_time=stamp,
                                 data=json.dumps(record, separators=(",", ":")).encode(),
                                 publish_time=stamp, sequence=self._sequence)
        self.messages += 1

    def telemetry(self, board: str, row: dict[str, Any]) -> None:
        self._add(board, "telemetry", row)

    def parameter(self, board: str, record: dict[str, Any]) -> None:
        self._add(board, "params", record)

    def event(self, board: str, record: dict[str, Any]) -> None:
        self._add(board, "events", record)

    def stats(self, board: str, record: dict[str, Any]) -> None:
        self._add(board, "stats", record)

    def close(self) -> None:
        try:
            self._writer.finish()  # type: ignore[no-untyped-call] # the summary and footer make the file valid and indexed
        finally:
            self._file.close()


class CsvSink:
    """Telemetry only, one row per TM sample (``board`` column first); the rest is dropped."""

    def __init__(self, path: Path) -> None:
        self._file: IO[str] = path.open("w", newline="", encoding="utf-8")
        self._writer = csv.DictWriter(self._file, fieldnames=["board", *TELEMETRY_FIELDS],
                                      lineterminator="\n")
        self._writer.writeheader()
        self.messages = 0

    def telemetry(self, board: str, row: dict[str, Any]) -> None:
        self._writer.writerow({"board": board, **row})
        self.messages += 1

    def parameter(self, board: str, record: dict[str, Any]) -> None:
        pass

    def event(self, board: str, record: dict[str, Any]) -> None:
        pass

    def stats(self, board: str, record: dict[str, Any]) -> None:
        pass

    def close(self) -> None:
        self._file.close()


def _parameter_record(message: Parsed) -> dict[str, Any] | None:
    if not isinstance(message, ParamAck | ParamNack):
        return None
    try:
        name = lookup(message.param_id).full_name(message.channel)
    except UnknownParameter:  # an id we do not know: still worth recording
        name = f"param{message.param_id}"
    record: dict[str, Any] = {"timestamp": time.time(), "name": name,
                              "param_id": message.param_id, "channel": message.channel}
    if isinstance(message, ParamAck):
        record.update(value=message.value, status="in_force", detail="")
    else:
        record.update(status="refused", detail=message.reason)
    return record


@click.command(epilog=EXIT_CODES_HELP)
@click.argument("file", type=click.Path(dir_okay=False, writable=True, path_type=Path))
@click.option("--duration", type=click.FloatRange(min=0, min_open=True),
              help="Stop after S seconds (default: until Ctrl-C).")
@click.option("--csv", "as_csv", is_flag=True,
              help="Write telemetry as CSV instead of MCAP.")
@click.option("--passive", is_flag=True,
              help="Only listen: no parameter snapshot, GetDataPeriodical left alone.")
@connection_options(multi=True)
def record(file: Path, duration: float | None, as_csv: bool, passive: bool,
           conn: ConnectionOptions) -> int:
    """Record telemetry, parameter changes and link events into FILE (MCAP).

    Topics per board NAME: /board/NAME/telemetry (flat numeric fields: timestamp, t_us,
    a_speed, b_pwm …), /board/NAME/params (every PA/PN the board sent: the initial snapshot
    and each change), /board/NAME/events (link events), /board/NAME/stats (1 Hz).
    Ctrl-C stops cleanly: the file is closed and valid (exit 130).
    """
    if file.exists() and file.is_dir():
        raise CliError(f"{file} is a directory", ExitCode.BAD_INPUT)
    return run(_record(conn, file, duration, as_csv, passive))


async def _record(conn: ConnectionOptions, path: Path, duration: float | None, as_csv: bool,
                  passive: bool) -> int:
    stop = asyncio.Event()
    install_stop_signals(stop)
    console = Console(stderr=True)
    started = time.monotonic()
    async with contextlib.AsyncExitStack() as stack:
        sessions = await open_sessions(stack, conn)
        boards = [s.endpoint.name for s in sessions]
        metadata = {"ports": " ".join(f"{s.endpoint.name}={s.endpoint.url}" for s in sessions),
                    "baud": str(conn.baud), "started": f"{time.time():.6f}"}
        try:
            sink: Sink = CsvSink(path) if as_csv else McapSink(path, boards, metadata)
        except OSError as exc:
            raise CliError(f"{path}: cannot write: {exc.strerror}", ExitCode.FAILURE) from None
        stack.callback(sink.close)  # runs last: after streaming is restored and links close
        tasks: list[asyncio.Task[None]] = []
        counts = dict.fromkeys(boards, 0)
        for session in sessions:
            _tap_parameters(session, sink)
            tasks.append(asyncio.ensure_future(_record_events(session, sink)))
        subs = [s.link.telemetry(maxsize=65536) for s in sessions]
        try:
            sink.event(boards[0], {"timestamp": time.time(), "kind": "recording_started",
                                   "detail": metadata["ports"]})
            if not passive:
                for session in sessions:
                    await session.link.read_params()  # the PA replies are the snapshot
            await start_streaming(sessions, passive)
            for session, sub in zip(sessions, subs, strict=True):
                tasks.append(asyncio.ensure_future(_record_telemetry(session, sub, sink, counts)))
                tasks.append(asyncio.ensure_future(_record_stats(session, sink)))
            await _progress(console, stop, duration, counts, path)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            with contextlib.suppress(Exception):
                await restore_streaming(sessions, passive)
            sink.event(boards[0], {"timestamp": time.time(), "kind": "recording_stopped",
                                   "detail": ""})
    total = sum(counts.values())
    elapsed = time.monotonic() - started
    click.echo(f"recorded {total} telemetry samples from {len(counts)} board(s) in "
               f"{elapsed:.1f} s to {path}", err=True)
    return stop_exit_code(stop)


def _tap_parameters(session: BoardSession, sink: Sink) -> None:
    name = session.endpoint.name

    def on_message(message: Parsed) -> None:
        rec = _parameter_record(message)
        if rec is not None:
            sink.parameter(name, rec)

    on_messages(session.link, on_message)


async def _record_events(session: BoardSession, sink: Sink) -> None:
    async for event in session.link.watch():
        sink.event(session.endpoint.name, {"timestamp": time.time(), "kind": event.kind.value,
                                           "detail": event.detail})


async def _record_telemetry(session: BoardSession, sub: Any, sink: Sink,
                            counts: dict[str, int]) -> None:
    name = session.endpoint.name
    async for sample in sub:
        row = {k: compact(v) for k, v in telemetry_row(sample, 0.0).items()}
        row["timestamp"] = session.clock.seconds(sample.t_us)
        sink.telemetry(name, row)
        counts[name] += 1


async def _record_stats(session: BoardSession, sink: Sink) -> None:
    while True:
        await asyncio.sleep(STATS_PERIOD_S)
        session.update_rate(time.monotonic())
        stats = session.link.stats
        rec: dict[str, Any] = {"timestamp": time.time(), "telemetry_rate": session.rate}
        for name in STATS_FIELDS[1:]:
            rec[name] = getattr(stats, name)
        sink.stats(session.endpoint.name, rec)


async def _progress(console: Console, stop: asyncio.Event, duration: float | None,
                    counts: dict[str, int], path: Path) -> None:
    columns = [SpinnerColumn(), TextColumn("recording to {task.fields[path]}")]
    if duration is not None:
        columns.append(BarColumn())
    columns += [TimeElapsedColumn(), TextColumn("{task.fields[samples]} samples")]
    started = time.monotonic()
    deadline = None if duration is None else started + duration
    with Progress(*columns, console=console, disable=not console.is_terminal) as progress:
        task = progress.add_task("record", total=duration, path=str(path), samples=0)
        while not stop.is_set():
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            progress.update(task, completed=now - started, samples=sum(counts.values()))
            wait = 0.1 if deadline is None else min(0.1, max(0.0, deadline - now))
            await wait_or_stop(stop, wait)
        progress.update(task, completed=time.monotonic() - started,
                        samples=sum(counts.values()))
