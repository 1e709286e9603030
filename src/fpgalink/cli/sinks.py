"""Where ``record`` writes: MCAP (the library's writer, :mod:`fpgalink.recording`) or CSV.
Both go the way every recording goes (:mod:`fpgalink.recording.files`): written as
``NAME.partial`` and renamed into place when complete, an existing file refused unless
``--force``. Both survive what a disk can do to them:

* chunks are closed (MCAP) and rows flushed (CSV) every half second, so a hard kill loses at
  most that much, and what was written stays readable (in ``NAME.partial``);
* room for the MCAP file's own summary is reserved ahead of the data, so when the disk fills
  the recording stops with an error *and* a complete file; CSV ends at its last complete row.

A write that fails raises :class:`~fpgalink.recording.RecordingError` and stops the
recording; ``close`` then says, by raising it, what is on disk (one line, exit 1).

MCAP times (``docs/cli.md``): ``log_time`` is when the host received the message (the MCAP
spec's meaning), ``publish_time`` is the board's sample time mapped onto the host clock, and
the payload keeps the board's raw ``t_us`` — so board/host clock drift shows.
"""

from __future__ import annotations

import contextlib
import csv
import io
import time
from pathlib import Path
from typing import IO, Any, Protocol

from fpgalink import __version__, recording
from fpgalink.recording import (
    EVENT_SCHEMA,
    FLUSH_S,
    PARAM_SCHEMA,
    STATS_FIELDS,
    STATS_SCHEMA,
    TELEMETRY_FIELDS,
    DiskFull,
    Output,
    RecordingError,
    ReservedSpace,
    describe_error,
    log_level,
)

__all__ = ["EVENT_SCHEMA", "PARAM_SCHEMA", "STATS_FIELDS", "STATS_SCHEMA", "CsvSink",
           "McapSink", "Sink", "log_level"]


class Sink(Protocol):
    @property
    def messages(self) -> int: ...

    def telemetry(self, board: str, row: dict[str, Any], received: float,
                  sampled: float) -> None: ...
    def parameter(self, board: str, record: dict[str, Any]) -> None: ...
    def event(self, board: str, kind: str, detail: str, at: float) -> None: ...
    def stats(self, board: str, record: dict[str, Any]) -> None: ...
    def close(self) -> None: ...


class McapSink(recording.McapSink):
    """The library's MCAP writer, named ``fpgalink-cli`` in the file's header."""

    def __init__(self, path: Path, boards: list[str], metadata: dict[str, str],
                 extra_topics: dict[str, dict[str, Any]] | None = None, *,
                 force: bool) -> None:
        super().__init__(path, boards, metadata, extra_topics,
                         library=f"fpgalink-cli {__version__}", force=force)


class CsvSink:
    """Telemetry only, one row per TM sample (``board`` column first); the rest is dropped.
    Rows are written whole: after a write error the file ends at the last complete row."""

    def __init__(self, path: Path, *, force: bool) -> None:
        self.path = path
        self._output = Output(path, force=force)
        self._file: IO[bytes] = self._output.file()
        self._space = ReservedSpace(self._file)
        self._buffer = io.StringIO()
        self._writer = csv.DictWriter(self._buffer, fieldnames=["board", *TELEMETRY_FIELDS],
                                      lineterminator="\n")
        self._writer.writeheader()
        self._flushed = time.monotonic()
        self.messages = 0
        self.rows_written = 0  #: rows that are in the file for certain
        self._pending = 0  # rows in the buffer (the header is not one)
        self.failure: OSError | None = None
        self._closed = False
        try:
            self._flush()
        except OSError as exc:
            self._closed = True
            with contextlib.suppress(OSError):
                self._file.close()
            self._output.discard()
            raise RecordingError(f"{path}: {describe_error(exc)}: the recording could not be "
                                 "started; no file left") from None

    def telemetry(self, board: str, row: dict[str, Any], received: float,
                  sampled: float) -> None:
        if self._closed:
            raise RecordingError(f"{self.path}: the recording is closed")
        if self.failure is not None:
            raise RecordingError(f"{self.path}: recording stopped: "
                                 f"{describe_error(self.failure)}")
        self._writer.writerow({"board": board, **row})
        self.messages += 1
        self._pending += 1
        if time.monotonic() - self._flushed >= FLUSH_S:
            self._flush_or_stop()

    def _flush_or_stop(self) -> None:
        try:
            self._flush()
        except OSError as exc:
            self.failure = exc
            raise RecordingError(f"{self.path}: recording stopped: {describe_error(exc)}"
                                 ) from None

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
        """The last rows, and the file in place; :class:`RecordingError` when the recording
        stopped early or the last rows could not be written."""
        if self._closed:
            return
        self._closed = True
        if self.failure is None:
            with contextlib.suppress(RecordingError):  # kept in self.failure, said below
                self._flush_or_stop()
        self._space.release()
        with contextlib.suppress(OSError):
            self._file.close()
        self._output.commit()  # whole rows up to the last written: complete up to there
        if self.failure is not None:
            raise RecordingError(f"{self.path}: {describe_error(self.failure)}; recording "
                                 f"stopped with {self.rows_written} complete rows in the "
                                 "file, which is complete up to there")
