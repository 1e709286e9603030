"""What a recording holds: the schemas of its topics (JSON Schema, so Foxglove and
PlotJuggler open the files as they are), telemetry as flat rows, and the records of
parameters and link events. The CLI's ``record``, ``drive`` and ``goto`` and the campaigns
write these through :class:`~fpgalink.recording.McapSink`, so their files read alike.

What a message's ``log_time`` and ``publish_time`` mean is the writer's caller's to say (in
the file's metadata): the CLI's are host epoch times (``docs/cli.md``), a campaign's are
emulated seconds from the scenario's start.
"""

from __future__ import annotations

import math
from typing import Any

from fpgalink.protocol import ParamAck, ParamNack, Parsed, Telemetry, lookup
from fpgalink.protocol.errors import UnknownParameter

__all__ = [
    "CHANNEL_FIELDS",
    "COMMAND_SCHEMA",
    "EVENT_SCHEMA",
    "PARAM_SCHEMA",
    "POSE_SCHEMA",
    "STATS_FIELDS",
    "STATS_SCHEMA",
    "TELEMETRY_FIELDS",
    "compact",
    "json_safe",
    "log_level",
    "log_record",
    "parameter_record",
    "telemetry_row",
    "telemetry_schema",
]

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
