"""Recordings on disk: the MCAP writer (JSON with JSON schemas, so Foxglove and PlotJuggler
open it as is), the schemas of its topics, and telemetry as flat rows. The CLI's ``record``,
``drive`` and ``goto`` and the campaigns (``docs/campaigns.md``) write through it, so their
files read alike; it stands on the protocol alone, below both (neither may import the other).

A recording survives what a disk can do to it:

* chunks are closed when full (64 KiB) and every half second, so a hard kill loses at most
  that much, and what was written stays readable; a writer abandoned (a signal's exception
  may break into a write) is cut back to its last complete chunk;
* room for the file's own summary is reserved ahead of the data with
  ``fallocate(FALLOC_FL_KEEP_SIZE)``, so when the disk fills the recording stops with an
  error *and* a complete file (:class:`DiskFull`); should a write fail all the same, the torn
  tail is cut back to the last complete chunk before the file is closed.

What a message's ``log_time`` and ``publish_time`` mean is the writer's caller's to say (in
the file's metadata): the CLI's are host epoch times (``docs/cli.md``), a campaign's are
emulated seconds from the scenario's start.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import json
import math
import os
import time
from pathlib import Path
from typing import IO, Any

from fpgalink.protocol import ParamAck, ParamNack, Parsed, Telemetry, lookup
from fpgalink.protocol.errors import FpgalinkError, UnknownParameter

__all__ = [
    "CHANNEL_FIELDS",
    "COMMAND_SCHEMA",
    "EVENT_SCHEMA",
    "PARAM_SCHEMA",
    "POSE_SCHEMA",
    "STATS_FIELDS",
    "STATS_SCHEMA",
    "TELEMETRY_FIELDS",
    "DiskFull",
    "McapSink",
    "RecordingError",
    "ReservedSpace",
    "compact",
    "json_safe",
    "log_level",
    "log_record",
    "parameter_record",
    "telemetry_row",
    "telemetry_schema",
]

#: Close a chunk this often: what a hard kill can lose.
FLUSH_S = 0.5
CHUNK_BYTES = 64 * 1024
#: Room kept allocated past the end of the data for the summary and the next chunk.
RESERVE_BYTES = 512 * 1024
#: One encoder for every message: ``json.dumps`` with options builds a new one per call,
#: a cost paid at every telemetry sample.
_ENCODE = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode


# --- telemetry as rows ------------------------------------------------------------------------

#: Per channel, in TM wire order; ``ref`` is the reference the board is following.
CHANNEL_FIELDS = ("position", "speed", "current", "pwm", "ref", "flags")
TELEMETRY_FIELDS = (
    "timestamp", "t_us", "counter",
    *(f"{ch}_{name}" for ch in ("a", "b") for name in CHANNEL_FIELDS),
)
_UNITS = {"position": "encoder counts", "speed": "deg/s", "current": "A",
          "pwm": "duty, ±32760 = ±100 %", "ref": "reference (deg/s or N·m)",
          "flags": "bit0 enable, bit1 end-stop, bit2 saturated"}


def json_safe(row: dict[str, Any]) -> dict[str, Any]:
    """JSON has no NaN or infinity: a non-finite number (a board can send one) is written as
    ``null``, so every line stays valid JSON (docs/cli.md)."""
    return {k: None if isinstance(v, float) and not math.isfinite(v) else v
            for k, v in row.items()}


def compact(value: Any) -> Any:
    """Floats from the wire are float32: 7 significant digits say all they hold."""
    if isinstance(value, float):
        return float(f"{value:.7g}")
    return value


def telemetry_row(sample: Telemetry, timestamp: float) -> dict[str, Any]:
    row: dict[str, Any] = {"timestamp": timestamp, "t_us": sample.t_us,
                           "counter": sample.counter}
    for prefix, channel in (("a", sample.a), ("b", sample.b)):
        for name, value in zip(CHANNEL_FIELDS, channel, strict=True):
            row[f"{prefix}_{name}"] = value
    return row


def telemetry_schema() -> dict[str, Any]:
    """JSON Schema of a row: flat numeric fields, so Foxglove and PlotJuggler plot
    ``/board/<name>/telemetry.a_speed`` without configuration."""
    properties: dict[str, Any] = {
        "timestamp": {"type": "number", "description": "host epoch time of the sample, s"},
        "t_us": {"type": "integer", "description": "board time, µs (wraps at 2^32)"},
        "counter": {"type": "integer", "description": "the TM message counter"},
    }
    for prefix in ("a", "b"):
        for name in CHANNEL_FIELDS:
            kind = "integer" if name in ("position", "pwm", "flags") else "number"
            properties[f"{prefix}_{name}"] = {
                "type": kind, "description": f"channel {prefix.upper()} {_UNITS[name]}"
            }
    return {"title": "fpgalink.Telemetry", "type": "object", "properties": properties,
            "required": list(TELEMETRY_FIELDS)}


# --- the other topics' schemas ----------------------------------------------------------------

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
#: ``/robot/odometry`` and ``/robot/truth``: the body's pose and speeds (a truth record
#: carries more: distance, surface, each board as the emulator sees it).
POSE_SCHEMA: dict[str, Any] = {
    "title": "fpgalink.Pose2D", "type": "object",
    "properties": {"t": {"type": "number"}, "x": {"type": "number"},
                   "y": {"type": "number"}, "theta": {"type": "number"},
                   "v": {"type": "number"}, "omega": {"type": "number"}},
}
#: ``/robot/command``: the body command in force and the wheel speeds it became.
COMMAND_SCHEMA: dict[str, Any] = {
    "title": "fpgalink.BodyCommand", "type": "object",
    "properties": {"v": {"type": "number"}, "omega": {"type": "number"},
                   "left": {"type": "number"}, "right": {"type": "number"},
                   "scale": {"type": "number"}},
}


def log_level(kind: str) -> int:
    """The foxglove.Log level of a link event."""
    return 3 if kind in ("board_lost", "port_lost") else 2


def log_record(kind: str, detail: str, at: float, name: str, level: int | None = None
               ) -> dict[str, Any]:
    """A foxglove.Log message for an event of ``name`` (a board, the robot) at ``at`` s."""
    return {"timestamp": {"sec": int(at), "nsec": int(at % 1 * 1e9)},
            "level": log_level(kind) if level is None else level,
            "message": f"{kind}: {detail}" if detail else kind, "name": name,
            "file": "", "line": 0}


def parameter_record(message: Parsed, timestamp: float) -> dict[str, Any] | None:
    """A board's ``PA`` (value in force) or ``PN`` (refused) as a ``/params`` message;
    ``None`` for any other message."""
    if not isinstance(message, ParamAck | ParamNack):
        return None
    try:
        name = lookup(message.param_id).full_name(message.channel)
    except UnknownParameter:  # an id we do not know: still worth recording
        name = f"param{message.param_id}"
    record: dict[str, Any] = {"timestamp": timestamp, "name": name,
                              "param_id": message.param_id, "channel": message.channel}
    if isinstance(message, ParamAck):
        record.update(value=message.value, status="in_force", detail="")
    else:
        record.update(status="refused", detail=message.reason)
    return json_safe(record)


# --- the disk ---------------------------------------------------------------------------------


class DiskFull(OSError):
    """The disk has no more room: the recording stopped, its file complete up to here."""


class RecordingError(FpgalinkError):
    """A recording could not be finished; its file is complete up to its last chunk."""


_FALLOC_FL_KEEP_SIZE = 1


def _fallocate() -> Any:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        function = libc.fallocate
    except (OSError, AttributeError):
        return None
    function.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
    return function


class ReservedSpace:
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
    ``/stats``; plus ``extra_topics`` (topic → JSON schema), such as ``/robot/truth`` when an
    emulated robot's true pose is recorded. ``library`` names the writer in the file's
    header. :class:`OSError` when the file cannot be written (:class:`DiskFull` when the
    disk has no room)."""

    def __init__(self, path: Path, boards: list[str], metadata: dict[str, str],
                 extra_topics: dict[str, dict[str, Any]] | None = None, *,
                 library: str) -> None:
        from mcap.writer import Writer

        self.path = path
        self._file: IO[bytes] = path.open("wb")
        try:
            self._space = ReservedSpace(self._file)
            self._writer = Writer(self._file, chunk_size=CHUNK_BYTES)
            self._writer.start(profile="", library=library)
            schemas = {
                kind: self._writer.register_schema(
                    name=schema["title"], encoding="jsonschema",
                    data=json.dumps(schema).encode())
                for kind, schema in (("telemetry", telemetry_schema()),
                                     ("params", PARAM_SCHEMA), ("events", EVENT_SCHEMA),
                                     ("stats", STATS_SCHEMA))
            }
            self._channels = {
                f"/board/{board}/{kind}": self._writer.register_channel(
                    topic=f"/board/{board}/{kind}", message_encoding="json",
                    schema_id=schema_id)
                for board in boards for kind, schema_id in schemas.items()
            }
            for topic, schema in (extra_topics or {}).items():
                schema_id = self._writer.register_schema(
                    name=schema["title"], encoding="jsonschema",
                    data=json.dumps(schema).encode())
                self._channels[topic] = self._writer.register_channel(
                    topic=topic, message_encoding="json", schema_id=schema_id)
            self._writer.add_metadata("fpgalink", metadata)
            self._writer.flush()  # type: ignore[no-untyped-call]
            self._space.mark_good()
        except BaseException:
            with contextlib.suppress(OSError):
                self._file.close()
            raise
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
                data=_ENCODE(record).encode(),
                publish_time=log_ns if publish_time is None else int(publish_time * 1e9),
                sequence=self._sequence)
            self.messages += 1
            # The writer writes to the file only when a chunk is full, whole: once on disk,
            # the file is complete there, an abandoned file is cut back no further, and the
            # room for the summary is reserved again past it (a fast writer fills more
            # than the reserve between timed flushes).
            if self._file.tell() != self._space.good:
                self._space.mark_good()
            if time.monotonic() - self._flushed >= FLUSH_S:
                self._flush()
        except OSError:
            self._space.cut_back()
            raise

    def metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record (``name``: key → text) beside the one given at the start."""
        try:
            self._writer.add_metadata(name, data)  # closes the chunk: complete here
            self._space.mark_good()
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
        self.add(f"/board/{board}/events", log_record(kind, detail, at, board), at)

    def stats(self, board: str, record: dict[str, Any]) -> None:
        self.add(f"/board/{board}/stats", record, record["timestamp"])

    def abandon(self) -> None:
        """Close the file as it stands, cut back to its last complete chunk, without a
        summary: for a writer that may have been interrupted in the middle of a message (a
        signal's exception), whose pending chunk cannot be trusted. mcap's
        ``NonSeekingReader`` reads what is there."""
        if self._closed:
            return
        self._closed = True
        self._space.cut_back()
        with contextlib.suppress(OSError):
            self._file.close()

    def close(self) -> None:
        """Write the summary and footer (the file then opens with ``make_reader``);
        :class:`RecordingError` when they cannot be written."""
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
            raise RecordingError(f"{self.path}: cannot finish the recording: "
                                 f"{exc.strerror or exc}; complete up to the last chunk "
                                 "(read it with mcap's NonSeekingReader)") from None
        finally:
            self._file.close()
