"""Where ``record`` writes: MCAP (JSON with JSON schemas, so Foxglove and PlotJuggler open it
as is) or CSV. Both survive what a disk can do to them:

* chunks are closed (MCAP) and rows flushed (CSV) every half second, so a hard kill loses at
  most that much, and what was written stays readable;
* room for the MCAP file's own summary is reserved ahead of the data with
  ``fallocate(FALLOC_FL_KEEP_SIZE)``, so when the disk fills the recording stops with an
  error *and* a complete file (:class:`DiskFull`); should a write fail all the same, the torn
  tail is cut back to the last complete chunk (or row) before the file is closed.

MCAP times (``docs/cli.md``): ``log_time`` is when the host received the message (the MCAP
spec's meaning), ``publish_time`` is the board's sample time mapped onto the host clock, and
the payload keeps the board's raw ``t_us`` — so board/host clock drift shows.
"""

from __future__ import annotations

import contextlib
import csv
import ctypes
import ctypes.util
import errno
import io
import json
import os
import time
from pathlib import Path
from typing import IO, Any, Protocol

from fpgalink import __version__
from fpgalink.cli.output import CliError, ExitCode

__all__ = ["EVENT_SCHEMA", "CsvSink", "DiskFull", "McapSink", "Sink", "log_level"]

#: Close a chunk / flush rows this often: what a hard kill can lose.
FLUSH_S = 0.5
CHUNK_BYTES = 64 * 1024
#: Room kept allocated past the end of the data for the summary and the next chunk.
RESERVE_BYTES = 512 * 1024

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
#: Foxglove's foxglove.Log, so its Log panel shows link events (schemas/jsonschema/Log.json in
#: foxglove/foxglove-sdk). Levels: 0 unknown, 1 debug, 2 info, 3 warning, 4 error, 5 fatal.
EVENT_SCHEMA: dict[str, Any] = {
    "title": "foxglove.Log", "type": "object",
    "description": "A log message",
    "properties": {
        "timestamp": {"type": "object", "title": "time",
                      "properties": {"sec": {"type": "integer", "minimum": 0},
                                     "nsec": {"type": "integer", "minimum": 0,
                                              "maximum": 999999999}}},
        "level": {"title": "foxglove.LogLevel", "description": "Log level",
                  "oneOf": [{"title": name, "const": value} for name, value in
                            (("UNKNOWN", 0), ("DEBUG", 1), ("INFO", 2), ("WARNING", 3),
                             ("ERROR", 4), ("FATAL", 5))]},
        "message": {"type": "string", "description": "Log message"},
        "name": {"type": "string", "description": "Process or node name"},
        "file": {"type": "string", "description": "Filename"},
        "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"},
    },
    "required": ["timestamp", "level", "message", "name", "file", "line"],
}
STATS_FIELDS = ("telemetry_rate", "telemetry_received", "lost", "decode_errors", "malformed",
                "retries", "heartbeat_misses", "alive_received", "subscriber_drops",
                "port_losses", "reconnects", "references_superseded", "echo_mismatches")
STATS_SCHEMA: dict[str, Any] = {
    "title": "fpgalink.LinkStats", "type": "object",
    "properties": {"timestamp": {"type": "number"},
                   **{name: {"type": "number"} for name in STATS_FIELDS}},
}


def log_level(kind: str) -> int:
    """The foxglove.Log level of a link event."""
    return 3 if kind in ("board_lost", "port_lost") else 2


class DiskFull(OSError):
    """The disk has no more room: the recording stopped, its file complete up to here."""


class Sink(Protocol):
    messages: int

    def telemetry(self, board: str, row: dict[str, Any], received: float,
                  sampled: float) -> None: ...
    def parameter(self, board: str, record: dict[str, Any]) -> None: ...
    def event(self, board: str, kind: str, detail: str, at: float) -> None: ...
    def stats(self, board: str, record: dict[str, Any]) -> None: ...
    def close(self) -> None: ...


_FALLOC_FL_KEEP_SIZE = 1


def _fallocate() -> Any:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        function = libc.fallocate
    except (OSError, AttributeError):
        return None
    function.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
    return function


class _Reserved:
    """Keeps disk space allocated past the end of a file (the file's size does not change),
    and knows where its content was last complete."""

    def __init__(self, file: IO[bytes]) -> None:
        self._file = file
        self._fallocate = _fallocate()
        self.good = 0  #: the offset up to which the file is complete

    def mark_good(self) -> None:
        """The file is complete as it stands: remember where, and reserve room ahead
        (:class:`DiskFull` when there is none)."""
        self._file.flush()
        self.good = self._file.tell()
        if self._fallocate is None:
            return
        if self._fallocate(self._file.fileno(), _FALLOC_FL_KEEP_SIZE, self.good,
                           RESERVE_BYTES) != 0:
            code = ctypes.get_errno()
            if code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
                raise DiskFull(code, os.strerror(code))
            self._fallocate = None  # not supported here: writes will tell

    def cut_back(self) -> None:
        """Drop whatever came after the last complete state (a torn chunk or row)."""
        with contextlib.suppress(OSError, ValueError):
            self._file.seek(self.good)
            self._file.truncate(self.good)


class McapSink:
    """Topics per board: ``/board/<name>/telemetry``, ``/params``, ``/events`` (foxglove.Log),
    ``/stats``; plus ``/truth`` when an emulated robot's true pose is recorded."""

    def __init__(self, path: Path, boards: list[str], metadata: dict[str, str],
                 extra_topics: dict[str, dict[str, Any]] | None = None) -> None:
        from mcap.writer import Writer

        from fpgalink.cli.session import telemetry_schema

        self.path = path
        self._file: IO[bytes] = path.open("wb")
        self._space = _Reserved(self._file)
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
            f"/board/{board}/{kind}": self._writer.register_channel(
                topic=f"/board/{board}/{kind}", message_encoding="json", schema_id=schema_id)
            for board in boards for kind, schema_id in schemas.items()
        }
        for topic, schema in (extra_topics or {}).items():
            schema_id = self._writer.register_schema(
                name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode())
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id)
        self._writer.add_metadata("fpgalink", metadata)
        self._writer.flush()  # type: ignore[no-untyped-call]
        self._space.mark_good()
        self._sequence = 0
        self._flushed = time.monotonic()
        self.messages = 0
        self._closed = False

    def add(self, topic: str, record: dict[str, Any], log_time: float,
            publish_time: float | None = None) -> None:
        """One JSON message on ``topic`` (a channel given at the start)."""
        self._sequence += 1
        log_ns = int(log_time * 1e9)
        try:
            self._writer.add_message(
                self._channels[topic], log_time=log_ns,
                data=json.dumps(record, separators=(",", ":"), allow_nan=False).encode(),
                publish_time=log_ns if publish_time is None else int(publish_time * 1e9),
                sequence=self._sequence)
            self.messages += 1
            if time.monotonic() - self._flushed >= FLUSH_S:
                self._flush()
        except OSError:
            self._space.cut_back()
            raise

    def _flush(self) -> None:
        self._writer.flush()  # type: ignore[no-untyped-call]
        self._space.mark_good()
        self._flushed = time.monotonic()

    def telemetry(self, board: str, row: dict[str, Any], received: float,
                  sampled: float) -> None:
        self.add(f"/board/{board}/telemetry", row, received, sampled)

    def parameter(self, board: str, record: dict[str, Any]) -> None:
        self.add(f"/board/{board}/params", record, record["timestamp"])

    def event(self, board: str, kind: str, detail: str, at: float) -> None:
        message = f"{kind}: {detail}" if detail else kind
        record = {"timestamp": {"sec": int(at), "nsec": int(at % 1 * 1e9)},
                  "level": log_level(kind), "message": message, "name": board,
                  "file": "", "line": 0}
        self.add(f"/board/{board}/events", record, at)

    def stats(self, board: str, record: dict[str, Any]) -> None:
        self.add(f"/board/{board}/stats", record, record["timestamp"])

    def close(self) -> None:
        """Write the summary and footer (the file then opens with ``make_reader``)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()  # type: ignore[no-untyped-call]
            self._file.flush()
        except OSError as exc:
            # Not even the summary fits: cut back to the last complete chunk, so a linear
            # reader gets every message of it (docs/cli.md says how).
            self._space.cut_back()
            raise CliError(f"{self.path}: cannot finish the recording: {exc.strerror or exc}; "
                           "complete up to the last chunk (read it with mcap's "
                           "NonSeekingReader)", ExitCode.FAILURE) from None
        finally:
            self._file.close()


class CsvSink:
    """Telemetry only, one row per TM sample (``board`` column first); the rest is dropped.
    Rows are written whole: after a write error the file ends at the last complete row."""

    def __init__(self, path: Path) -> None:
        from fpgalink.cli.session import TELEMETRY_FIELDS

        self.path = path
        self._file: IO[bytes] = path.open("wb")
        self._space = _Reserved(self._file)
        self._buffer = io.StringIO()
        self._writer = csv.DictWriter(self._buffer, fieldnames=["board", *TELEMETRY_FIELDS],
                                      lineterminator="\n")
        self._writer.writeheader()
        self._flushed = time.monotonic()
        self.messages = 0
        self.rows_written = 0  #: rows that are in the file for certain
        self._pending = 0  # rows in the buffer (the header is not one)
        self._flush()

    def telemetry(self, board: str, row: dict[str, Any], received: float,
                  sampled: float) -> None:
        self._writer.writerow({"board": board, **row})
        self.messages += 1
        self._pending += 1
        if time.monotonic() - self._flushed >= FLUSH_S:
            self._flush()

    def _flush(self) -> None:
        try:
            self._file.write(self._buffer.getvalue().encode("utf-8"))
            self._space.mark_good()
        except DiskFull:
            self._written()  # the rows are in; there is no room for more
            raise
        except OSError:
            self._space.cut_back()
            raise
        self._written()

    def _written(self) -> None:
        self._buffer.seek(0)
        self._buffer.truncate()
        self.rows_written += self._pending
        self._pending = 0
        self._flushed = time.monotonic()

    def parameter(self, board: str, record: dict[str, Any]) -> None:
        pass

    def event(self, board: str, kind: str, detail: str, at: float) -> None:
        pass

    def stats(self, board: str, record: dict[str, Any]) -> None:
        pass

    def close(self) -> None:
        if self._file.closed:
            return
        try:
            self._flush()
        except OSError as exc:
            raise CliError(f"{self.path}: cannot write: {exc.strerror or exc}; the file holds "
                           f"{self.rows_written} complete rows", ExitCode.FAILURE) from None
        finally:
            self._file.close()
