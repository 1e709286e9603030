"""The MCAP writer every recording goes through: JSON messages with JSON schemas for the
CLI's and the campaigns' files (:class:`McapSink`), CDR for the rosbag2 bags
(:mod:`fpgalink.recording.bag`), both on :class:`McapFile`.

A recording survives what a disk can do to it:

* it is written as ``NAME.partial`` and renamed into place when complete
  (:class:`~fpgalink.recording.files.Output`): a target is complete or absent, never half;
* chunks (zstd, each with the CRC of its content, and the data section's CRC at the end, so
  a reader finds damage) are closed when full (64 KiB) and every half second, so a hard kill
  loses at most that much, and what was written stays readable;
* room for the file's own summary is reserved ahead of the data with
  ``fallocate(FALLOC_FL_KEEP_SIZE)``, so when the disk fills the recording stops
  (:class:`~fpgalink.recording.files.DiskFull`) *and* is closed with its summary, complete up
  to there; any other write error leaves a writer whose state cannot be trusted, so the file
  is cut back to its last complete chunk and kept, without summary, as ``NAME.partial``
  (removed when it holds no message).

Every failure is a :class:`~fpgalink.recording.files.RecordingError` whose one line says what
is left on disk.
"""

from __future__ import annotations

import contextlib
import json
import time
from pathlib import Path
from typing import IO, Any

from fpgalink.recording.files import DiskFull, Output, RecordingError, ReservedSpace
from fpgalink.recording.topics import (
    EVENT_SCHEMA,
    PARAM_SCHEMA,
    STATS_SCHEMA,
    log_record,
    telemetry_schema,
)

__all__ = ["CHUNK_BYTES", "FLUSH_S", "Lifecycle", "McapFile", "McapSink", "Recorded",
           "describe_error"]

#: Close a chunk this often: what a hard kill can lose.
FLUSH_S = 0.5
CHUNK_BYTES = 64 * 1024
#: One encoder for every message: ``json.dumps`` with options builds a new one per call,
#: a cost paid at every telemetry sample.
_ENCODE = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode


def describe_error(exc: BaseException) -> str:
    """A write error as the one line says it."""
    if isinstance(exc, DiskFull):
        return "the disk is full"
    if isinstance(exc, OSError):
        return f"cannot write: {exc.strerror or exc}"
    return f"cannot write: {exc}"


class McapFile:
    """One MCAP file being written to ``file``. :class:`OSError` from any call that writes
    (:class:`DiskFull` when the reserve ahead cannot be kept: the file is then complete and
    :meth:`finish` still fits; any other: the file is cut back to its last complete chunk
    and :attr:`consistent` is false — :meth:`finish` must not be tried)."""

    def __init__(self, file: IO[bytes], *, library: str, profile: str = "") -> None:
        from mcap.writer import Writer

        self._file = file
        self._space = ReservedSpace(file)
        self._writer = Writer(file, chunk_size=CHUNK_BYTES, enable_data_crcs=True)
        self._sequence = 0
        self._flushed = time.monotonic()
        self.messages = 0  #: messages added
        self.durable = 0  #: of them, those in complete chunks on disk
        self.first_ns: int | None = None  #: the first message's log time
        self.last_ns = 0  #: the latest log time
        self.consistent = True  #: whether the writer's state matches the file's
        self._guarded(self._writer.start, profile=profile, library=library)
        # Room for the summary before anything else: a disk without it refuses at once.
        self._guarded(self._space.mark_good)

    def schema(self, name: str, encoding: str, data: bytes) -> int:
        schema_id: int = self._guarded(self._writer.register_schema, name=name,
                                       encoding=encoding, data=data)
        return schema_id

    def channel(self, topic: str, message_encoding: str, schema_id: int,
                metadata: dict[str, str] | None = None) -> int:
        channel_id: int = self._guarded(self._writer.register_channel, topic=topic,
                                        message_encoding=message_encoding,
                                        schema_id=schema_id, metadata=metadata or {})
        return channel_id

    def add(self, channel_id: int, data: bytes, log_ns: int, publish_ns: int) -> None:
        self._sequence += 1
        self._guarded(self._writer.add_message, channel_id, log_time=log_ns, data=data,
                      publish_time=publish_ns, sequence=self._sequence)
        self.messages += 1
        if self.first_ns is None:
            self.first_ns = log_ns
        self.last_ns = max(self.last_ns, log_ns)
        # The writer writes to the file only when a chunk is full, whole (this message in
        # it): once on disk, the file is complete there, a failure cuts it back no further,
        # and the room for the summary is reserved again past it (a fast writer fills more
        # than the reserve between timed flushes).
        if self._file.tell() != self._space.good:
            self._landed()
        if time.monotonic() - self._flushed >= FLUSH_S:
            self.flush()

    def flush(self) -> None:
        """Close the chunk in progress: what was added is on disk, complete."""
        self._guarded(self._writer.flush)
        self._landed()
        self._flushed = time.monotonic()

    def metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record (closes the chunk in progress: complete here)."""
        self._guarded(self._writer.add_metadata, name, data)
        self._landed()

    def _landed(self) -> None:
        self.durable = self.messages
        self._guarded(self._space.mark_good)

    def _guarded(self, call: Any, *args: Any, **kwargs: Any) -> Any:
        try:
            return call(*args, **kwargs)
        except DiskFull:
            raise  # said before anything was torn: the writer and the file agree
        except OSError:
            self.consistent = False
            self._space.cut_back()
            raise

    def finish(self) -> None:
        """The summary and footer (the file then opens with ``make_reader``)."""
        assert self.consistent
        self._guarded(self._writer.finish)
        self._guarded(self._file.flush)
        self._space.release()

    def cut_back(self) -> None:
        """Back to the last complete chunk, for a writer that may have been interrupted in
        the middle of a message (a signal's exception) or failed."""
        self._space.cut_back()


class Lifecycle:
    """What every MCAP recording shares (a JSON recording, a rosbag2): it stops at its first
    failed write (every later one raises again), and it ends one way: finished and put in
    place (one line saying so if it stopped early); kept as ``NAME.partial`` without summary
    when its writer cannot be trusted to finish; or removed when it holds no message.
    ``noun`` names it in the lines (``file``, ``bag``)."""

    def __init__(self, target: Path, output: Output, noun: str) -> None:
        self.target = target
        self.output = output
        self.noun = noun
        self.mcap: McapFile | None = None  #: set once the file is begun
        self.failure: BaseException | None = None
        self.in_place = False  #: ended, and at ``target`` (complete up to where it got)
        self.closed = False

    def not_started(self, exc: OSError) -> RecordingError:
        """The recording could not begin: nothing is left."""
        self.closed = True
        self.output.discard()
        return RecordingError(f"{self.target}: {describe_error(exc)}: the recording could not "
                              f"be started; no {self.noun} left")

    def write(self, call: Any, *args: Any, **kwargs: Any) -> Any:
        """``call``, unless the recording has stopped or ended; an :class:`OSError` from it
        stops the recording: :class:`RecordingError`."""
        if self.closed:
            raise RecordingError(f"{self.target}: the recording is closed")
        if self.failure is not None:
            raise RecordingError(f"{self.target}: recording stopped: "
                                 f"{describe_error(self.failure)}")
        try:
            return call(*args, **kwargs)
        except OSError as exc:
            self.failure = exc
            raise RecordingError(f"{self.target}: recording stopped: {describe_error(exc)}"
                                 ) from None

    def end(self, finish: Any, abandon: Any, kept_hint: str) -> None:
        """``finish()`` writes the summary (and what else the format needs); ``abandon()``
        leaves the file as it stands. :class:`RecordingError` saying what is on disk when
        the recording stopped early or cannot be finished."""
        if self.closed:
            return
        self.closed = True
        mcap = self.mcap
        assert mcap is not None
        problem = self.failure
        if mcap.consistent and (problem is None or mcap.messages):
            try:
                finish()
            except OSError as exc:
                problem = problem or exc
            else:
                self.output.commit()
                self.in_place = True
                if problem is None:
                    return
                span = "" if mcap.first_ns is None else \
                    f" after {(mcap.last_ns - mcap.first_ns) / 1e9:.1f} s"
                raise RecordingError(
                    f"{self.target}: {describe_error(problem)}; recording stopped{span} with "
                    f"{mcap.messages} messages in the {self.noun}, which is complete up to "
                    "there")
        with contextlib.suppress(Exception):
            abandon()
        assert problem is not None
        if mcap.durable:
            self.output.keep_partial()
            raise RecordingError(
                f"{self.target}: {describe_error(problem)}; the recording could not be "
                f"finished: its {mcap.durable} messages in complete chunks are in "
                f"{self.output.path} ({kept_hint})")
        self.output.discard()
        raise RecordingError(f"{self.target}: {describe_error(problem)}; nothing was recorded, "
                             f"no {self.noun} left")


class Recorded:
    """What a recording tells of itself, from its :class:`Lifecycle`."""

    _life: Lifecycle

    @property
    def messages(self) -> int:
        """Messages written so far."""
        mcap = self._life.mcap
        return 0 if mcap is None else mcap.messages

    @property
    def failure(self) -> BaseException | None:
        """The write error that stopped the recording, if one did."""
        return self._life.failure

    @property
    def in_place(self) -> bool:
        """Closed, and at its target (complete up to where it got)."""
        return self._life.in_place


class McapSink(Recorded):
    """A JSON recording at ``target``: topics per board, ``/board/<name>/telemetry``,
    ``/params``, ``/events`` (foxglove.Log), ``/stats``; plus ``extra_topics`` (topic →
    JSON schema), such as ``/robot/truth``. ``library`` names the writer in the file's
    header. ``force``: replace a target that exists (else :class:`OutputRefused`).

    A write that fails raises :class:`RecordingError` and stops the recording (every later
    write raises it again); :meth:`close` then finishes the file as well as it can and raises
    the one line that says what is on disk (:class:`Lifecycle`). :class:`RecordingError`
    from the start when the file cannot be begun (nothing is left)."""

    def __init__(self, target: Path, boards: list[str], metadata: dict[str, str],
                 extra_topics: dict[str, dict[str, Any]] | None = None, *,
                 library: str, force: bool = False) -> None:
        self.path = target
        output = Output(target, force=force)
        self._life = Lifecycle(target, output, "file")
        self._file = output.file()
        try:
            self._mcap = self._life.mcap = McapFile(self._file, library=library)
            schemas = {
                kind: self._mcap.schema(schema["title"], "jsonschema",
                                        json.dumps(schema).encode())
                for kind, schema in (("telemetry", telemetry_schema()),
                                     ("params", PARAM_SCHEMA), ("events", EVENT_SCHEMA),
                                     ("stats", STATS_SCHEMA))
            }
            self._channels = {
                f"/board/{board}/{kind}": self._mcap.channel(f"/board/{board}/{kind}", "json",
                                                             schema_id)
                for board in boards for kind, schema_id in schemas.items()
            }
            for topic, schema in (extra_topics or {}).items():
                schema_id = self._mcap.schema(schema["title"], "jsonschema",
                                              json.dumps(schema).encode())
                self._channels[topic] = self._mcap.channel(topic, "json", schema_id)
            self._mcap.metadata("fpgalink", metadata)
        except BaseException as exc:
            with contextlib.suppress(OSError):
                self._file.close()
            if isinstance(exc, OSError):
                raise self._life.not_started(exc) from None
            output.discard()
            raise

    def add(self, topic: str, record: dict[str, Any], log_time: float,
            publish_time: float | None = None) -> None:
        """One JSON message on ``topic`` (a channel given at the start)."""
        log_ns = int(log_time * 1e9)
        self._life.write(self._mcap.add, self._channels[topic], _ENCODE(record).encode(),
                         log_ns, log_ns if publish_time is None else int(publish_time * 1e9))

    def metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record (``name``: key → text) beside the one given at the start."""
        self._life.write(self._mcap.metadata, name, data)

    def telemetry(self, board: str, row: dict[str, Any], received: float,
                  sampled: float) -> None:
        self.add(f"/board/{board}/telemetry", row, received, sampled)

    def parameter(self, board: str, record: dict[str, Any]) -> None:
        self.add(f"/board/{board}/params", record, record["timestamp"])

    def event(self, board: str, kind: str, detail: str, at: float) -> None:
        self.add(f"/board/{board}/events", log_record(kind, detail, at, board), at)

    def stats(self, board: str, record: dict[str, Any]) -> None:
        self.add(f"/board/{board}/stats", record, record["timestamp"])

    def abandon(self) -> None:
        """Stop where it stands, without summary: for a writer that may have been
        interrupted in the middle of a message (a signal's exception), whose pending chunk
        cannot be trusted. The file is cut back to its last complete chunk and kept as
        ``NAME.partial`` (removed if it holds no message); readers of a file without
        summary (``fpgalink-cli plot``, mcap's ``NonSeekingReader``) read it."""
        if self._life.closed:
            return
        self._life.closed = True
        self._cut()
        if self._mcap.durable:
            self._life.output.keep_partial()
        else:
            self._life.output.discard()

    def _cut(self) -> None:
        self._mcap.cut_back()
        with contextlib.suppress(OSError):
            self._file.close()

    def _finish(self) -> None:
        self._mcap.finish()
        self._file.close()

    def close(self) -> None:
        """Finish: the summary and footer written, the file put in place. Raises
        :class:`RecordingError` when the recording stopped early or cannot be finished;
        its one line says what is on disk."""
        self._life.end(self._finish, self._cut,
                       "no summary; fpgalink-cli plot reads it")
