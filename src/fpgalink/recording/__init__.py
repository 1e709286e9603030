"""Recordings on disk: the MCAP writer every recording goes through (JSON with JSON schemas,
so Foxglove and PlotJuggler open it as is; the rosbag2 bags' CDR too), the schemas of its
topics and telemetry as flat rows, the one way a file is put in place, and the one way a
recording is read back. The CLI's ``record``, ``drive``, ``goto`` and ``--rosbag2``, the
campaigns and ``tune``, and the ROS 2 node's ``--bag`` write through it, so their files read
alike and fail alike; it stands on the protocol alone, below all of them.

* :mod:`~fpgalink.recording.topics` — what a recording holds: schemas, rows, records;
* :mod:`~fpgalink.recording.files` — where it goes: ``NAME.partial``, renamed into place
  when complete; an existing target refused unless asked; one writer at a time;
* :mod:`~fpgalink.recording.mcapfile` — the MCAP writer (:class:`McapSink`): chunks with
  CRCs, closed every half second, the summary's room reserved so a full disk leaves a
  complete file;
* :mod:`~fpgalink.recording.bag` — a rosbag2 through the same writer and the same path;
* :mod:`~fpgalink.recording.reader` — reading back, every chunk checked, damage named.
"""

from fpgalink.recording.bag import BagRecording, BagStorage
from fpgalink.recording.files import (
    PARTIAL_SUFFIX,
    DirectoryLock,
    DiskFull,
    Output,
    OutputBusy,
    OutputRefused,
    RecordingError,
    ReservedSpace,
    check_target,
    partial_path,
)
from fpgalink.recording.mcapfile import (
    CHUNK_BYTES,
    FLUSH_S,
    Lifecycle,
    McapFile,
    McapSink,
    describe_error,
)
from fpgalink.recording.reader import Damage, NotARecording, RecordingReader
from fpgalink.recording.topics import (
    CHANNEL_FIELDS,
    COMMAND_SCHEMA,
    EVENT_SCHEMA,
    PARAM_SCHEMA,
    POSE_SCHEMA,
    STATS_FIELDS,
    STATS_SCHEMA,
    TELEMETRY_FIELDS,
    compact,
    json_safe,
    log_level,
    log_record,
    parameter_record,
    telemetry_row,
    telemetry_schema,
)

__all__ = [
    "CHANNEL_FIELDS",
    "CHUNK_BYTES",
    "COMMAND_SCHEMA",
    "EVENT_SCHEMA",
    "FLUSH_S",
    "PARAM_SCHEMA",
    "PARTIAL_SUFFIX",
    "POSE_SCHEMA",
    "STATS_FIELDS",
    "STATS_SCHEMA",
    "TELEMETRY_FIELDS",
    "BagRecording",
    "BagStorage",
    "Damage",
    "DirectoryLock",
    "DiskFull",
    "Lifecycle",
    "McapFile",
    "McapSink",
    "NotARecording",
    "Output",
    "OutputBusy",
    "OutputRefused",
    "RecordingError",
    "RecordingReader",
    "ReservedSpace",
    "check_target",
    "compact",
    "describe_error",
    "json_safe",
    "log_level",
    "log_record",
    "parameter_record",
    "partial_path",
    "telemetry_row",
    "telemetry_schema",
]
