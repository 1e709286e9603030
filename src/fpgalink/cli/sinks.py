"""Where ``record`` writes: MCAP (the library's writer, :mod:`fpgalink.recording`) or CSV.
Both survive what a disk can do to them:

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

import csv
import io
import time
from pathlib import Path
from typing import IO, Any, Protocol

from fpgalink import __version__, recording
from fpgalink.cli.output import CliError, ExitCode
from fpgalink.recording import (
    EVENT_SCHEMA,
    FLUSH_S,
    PARAM_SCHEMA,
    STATS_FIELDS,
    STATS_SCHEMA,
    TELEMETRY_FIELDS,
    DiskFull,
    RecordingError,
    ReservedSpace,
    log_level,
)

__all__ = ["EVENT_SCHEMA", "PARAM_SCHEMA", "STATS_FIELDS", "STATS_SCHEMA", "CsvSink",
           "DiskFull", "McapSink", "Sink", "log_level"]


class Sink(Protocol):
    messages: int

    def telemetry(self, board: str, row: dict[str, Any], received: float,
                  sampled: float) -> None: ...
    def parameter(self, board: str, record: dict[str, Any]) -> None: ...
    def event(self, board: str, kind: str, detail: str, at: float) -> None: ...
    def stats(self, board: str, record: dict[str, Any]) -> None: ...
    def close(self) -> None: ...


class McapSink(recording.McapSink):
    """The library's MCAP writer, named ``fpgalink-cli`` in the file's header; a summary that
    cannot be written is the command's one-line error (exit 1)."""

    def __init__(self, path: Path, boards: list[str], metadata: dict[str, str],
                 extra_topics: dict[str, dict[str, Any]] | None = None) -> None:
        super().__init__(path, boards, metadata, extra_topics,
                         library=f"fpgalink-cli {__version__}")

    def close(self) -> None:
        try:
            super().close()
        except RecordingError as exc:
            raise CliError(str(exc), ExitCode.FAILURE) from None


class CsvSink:
    """Telemetry only, one row per TM sample (``board`` column first); the rest is dropped.
    Rows are written whole: after a write error the file ends at the last complete row."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._file: IO[bytes] = path.open("wb")
        self._space = ReservedSpace(self._file)
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
