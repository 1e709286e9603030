"""The wire, as SPEC §3–§5 define it: no I/O, no clock, no asyncio.

This package is the single home of the protocol. The host's :class:`~fpgalink.Connection`
stands on it, and so does the board emulator (``fpgaemu``): it is the only part of
``fpgalink`` that the emulator imports.

* :mod:`.framing` — ``S``/``P``/``\\`` framing: :func:`encode_frame`, :class:`FrameDecoder`;
* :mod:`.messages` — wire IDs (:class:`MessageId`), direct commands, counted messages;
* :mod:`.catalogue` — the typed messages ``PS PG PA PN RV TM``, :func:`parse_content`,
  :func:`encode_message`;
* :mod:`.params` — the parameter table (ranges, types, power-up defaults);
* :mod:`.counter` — the sender's counter and the receiver's gap/duplicate tracker;
* :mod:`.wire` — 8N1 wire-time arithmetic and budgets.
"""

from fpgalink.protocol.catalogue import (
    ChannelTelemetry,
    Message,
    NackReason,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    Parsed,
    References,
    Telemetry,
    TelemetryFlags,
    content_length,
    encode_message,
    parse_content,
)
from fpgalink.protocol.counter import CounterTracker, Observation, SendCounter
from fpgalink.protocol.errors import (
    FpgalinkError,
    LocalProtocolError,
    ParameterError,
    UnknownParameter,
)
from fpgalink.protocol.event import Event
from fpgalink.protocol.framing import (
    DEFAULT_FRAMING,
    AbortReason,
    FrameAborted,
    FrameDecoder,
    FrameTooLong,
    Framing,
    FramingError,
    FramingStats,
    NoiseDropped,
    encode_frame,
)
from fpgalink.protocol.messages import (
    COUNTER_MODULUS,
    Alive,
    Binary,
    CountedMessage,
    DirectCommand,
    Disable,
    Enable,
    Malformed,
    MalformedReason,
    MessageId,
    Role,
    Text,
)
from fpgalink.protocol.params import (
    PARAMETERS,
    Param,
    ParamType,
    Scope,
    float32,
    lookup,
    resolve,
)

__all__ = [
    "COUNTER_MODULUS",
    "DEFAULT_FRAMING",
    "PARAMETERS",
    "AbortReason",
    "Alive",
    "Binary",
    "ChannelTelemetry",
    "CountedMessage",
    "CounterTracker",
    "DirectCommand",
    "Disable",
    "Enable",
    "Event",
    "FpgalinkError",
    "FrameAborted",
    "FrameDecoder",
    "FrameTooLong",
    "Framing",
    "FramingError",
    "FramingStats",
    "LocalProtocolError",
    "Malformed",
    "MalformedReason",
    "Message",
    "MessageId",
    "NackReason",
    "NoiseDropped",
    "Observation",
    "Param",
    "ParamAck",
    "ParamGet",
    "ParamNack",
    "ParamSet",
    "ParamType",
    "ParameterError",
    "Parsed",
    "References",
    "Role",
    "Scope",
    "SendCounter",
    "Telemetry",
    "TelemetryFlags",
    "Text",
    "UnknownParameter",
    "content_length",
    "encode_frame",
    "encode_message",
    "float32",
    "lookup",
    "parse_content",
    "resolve",
]
