"""fpgalink: host library for the FPGA motor-controller UART protocol.

The core (framing, messages, catalogue, :class:`Connection`) is sans-I/O: bytes in, events
out, time passed in. :func:`open_link` (in :mod:`fpgalink.aio`) puts asyncio on top.
"""

from typing import TYPE_CHECKING

from fpgalink._counter import CounterTracker, Observation, SendCounter
from fpgalink._framing import (
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
from fpgalink._messages import (
    Alive,
    Binary,
    CountedMessage,
    DirectCommand,
    Disable,
    Enable,
    Malformed,
    MalformedReason,
    Text,
)
from fpgalink.catalogue import (
    ChannelTelemetry,
    Message,
    NackReason,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    References,
    Telemetry,
    TelemetryFlags,
    encode_message,
    parse_content,
)
from fpgalink.connection import (
    BoardFound,
    BoardSilent,
    Connection,
    CounterDuplicate,
    CounterGap,
    CounterLate,
    EventsDropped,
    LinkStats,
    RequestDone,
    RequestFailed,
    Role,
)
from fpgalink.errors import (
    BoardLost,
    FpgalinkError,
    LinkClosed,
    LocalProtocolError,
    ParameterError,
    ParameterRefused,
    PortError,
    RequestTimeout,
    UnknownParameter,
)
from fpgalink.params import PARAMETERS, Param, ParamType, Scope, lookup, resolve

__version__ = "0.1.0"

# The asyncio layer is imported on first use, so the sans-I/O core never pulls in asyncio;
# type checkers see the real names.
if TYPE_CHECKING:
    from fpgalink.aio.link import (
        Link,
        LinkEvent,
        LinkEventKind,
        LinkState,
        SyncResult,
        TelemetrySubscription,
        open_link,
    )

_AIO_NAMES = ("Link", "LinkEvent", "LinkEventKind", "LinkState", "SyncResult",
              "TelemetrySubscription", "open_link")


def __getattr__(name: str) -> object:
    if name in _AIO_NAMES:
        from fpgalink.aio import link

        return getattr(link, name)
    raise AttributeError(f"module 'fpgalink' has no attribute {name!r}")


__all__ = [
    "DEFAULT_FRAMING",
    "PARAMETERS",
    "AbortReason",
    "Alive",
    "Binary",
    "BoardFound",
    "BoardLost",
    "BoardSilent",
    "ChannelTelemetry",
    "Connection",
    "CountedMessage",
    "CounterDuplicate",
    "CounterGap",
    "CounterLate",
    "CounterTracker",
    "DirectCommand",
    "Disable",
    "Enable",
    "EventsDropped",
    "FpgalinkError",
    "FrameAborted",
    "FrameDecoder",
    "FrameTooLong",
    "Framing",
    "FramingError",
    "FramingStats",
    "Link",
    "LinkClosed",
    "LinkEvent",
    "LinkEventKind",
    "LinkState",
    "LinkStats",
    "LocalProtocolError",
    "Malformed",
    "MalformedReason",
    "Message",
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
    "ParameterRefused",
    "PortError",
    "References",
    "RequestDone",
    "RequestFailed",
    "RequestTimeout",
    "Role",
    "Scope",
    "SendCounter",
    "SyncResult",
    "Telemetry",
    "TelemetryFlags",
    "TelemetrySubscription",
    "Text",
    "UnknownParameter",
    "__version__",
    "encode_frame",
    "encode_message",
    "lookup",
    "open_link",
    "parse_content",
    "resolve",
]
