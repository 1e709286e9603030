"""The typed message catalogue of SPEC §4: ``PS PG PA PN RV TM``, and the optional board
identity pair ``IQ IA`` (docs/protocol.md): what each message is, not how it is read or
written (:mod:`.codec` does that).

Each body layout is declared once, as data, in :data:`BODIES`. The codec's :mod:`struct`
formats derive from it (:func:`body_format`); :func:`layout` derives a :mod:`construct`
description of the same layout on first use, for readers and tools (and a test checks both
agree on every message), so importing the protocol does not pay for construct.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, ClassVar, NamedTuple

from fpgalink.protocol.event import Event
from fpgalink.protocol.messages import (
    CountedMessage,
    DirectCommand,
    Malformed,
    MessageId,
)
from fpgalink.protocol.params import ParamType

__all__ = [
    "BODIES",
    "MESSAGE_TYPES",
    "ChannelTelemetry",
    "IdentityAnswer",
    "IdentityQuery",
    "Message",
    "NackReason",
    "ParamAck",
    "ParamGet",
    "ParamNack",
    "ParamSet",
    "Parsed",
    "References",
    "Telemetry",
    "TelemetryFlags",
    "body_format",
    "content_length",
    "layout",
    "pack_value",
    "unpack_value",
]


class NackReason(IntEnum):
    """``PN`` error codes (SPEC §4)."""

    UNKNOWN_ID = 1  #: no parameter has this id
    BAD_CHANNEL = 2  #: board parameter with channel ≠ 0, or channel parameter with 0 or > 2
    OUT_OF_RANGE = 3  #: value outside the range (NaN and infinities included)
    WRONG_TYPE = 4  #: type code is not the parameter's type
    #: not from a board: ``fpgalink-cli router`` refused it, another client controls the board
    NOT_CONTROLLER = 5

    @property
    def text(self) -> str:
        return {
            1: "unknown parameter id",
            2: "bad channel",
            3: "value out of range",
            4: "wrong value type",
            5: "another client controls the board",
        }[self.value]


class TelemetryFlags(IntEnum):
    ENABLE = 1  #: bit0: ``global_enable`` as the PWM stages see it
    END_STOP = 2  #: bit1: end-stop switch closed
    SATURATED = 4  #: bit2: controller output saturated


#: One field: its name, its :mod:`struct` code (little-endian) and what it holds.
Field = tuple[str, str, str]
#: A layout: fields, or ``(name, layout)`` for a nested one.
Layout = tuple["Field | tuple[str, Layout]", ...]

_CHANNEL_TM: Layout = (
    ("position", "i", "encoder counts"),
    ("speed", "f", "deg/s"),
    ("current", "f", "A"),
    ("pwm", "h", "applied duty, ±32760 = ±100 %"),
    ("reference", "f", "deg/s, or N·m under current control"),
    ("flags", "B", "bit0 enable, bit1 end-stop, bit2 saturated"),
)
_PARAM_VALUE: Layout = (
    ("param_id", "B", "parameter id"),
    ("channel", "B", "0 board, 1 A, 2 B"),
    ("value_type", "B", "1 int32, 2 float32"),
    ("value", "4s", "the value, as its type"),
)

#: Body layouts, each carried as one binary section: the single declaration. The ``struct``
#: formats of the hot path and the ``construct`` layouts (:func:`layout`) both derive from
#: it.
BODIES: dict[MessageId, Layout] = {
    MessageId.PS: _PARAM_VALUE,
    MessageId.PA: _PARAM_VALUE,
    MessageId.PG: (("param_id", "B", "parameter id"), ("channel", "B", "0 board, 1 A, 2 B")),
    MessageId.PN: (("param_id", "B", "parameter id"), ("channel", "B", "0 board, 1 A, 2 B"),
                   ("error", "B", "a NackReason code")),
    MessageId.RV: (("ref_a", "f", "channel A reference"), ("ref_b", "f", "channel B reference")),
    MessageId.TM: (("t_us", "I", "board time, µs, wraps"), ("a", _CHANNEL_TM), ("b", _CHANNEL_TM)),
    MessageId.IQ: (("nonce", "I", "echoed in the answer: which question it answers"),),
    MessageId.IA: (
        ("nonce", "I", "the query's nonce"),
        ("declarations", "Q", "the hash of the protocol declaration the firmware was built "
                              "from: every message and parameter layout"),
        ("firmware_major", "H", "firmware version, major"),
        ("firmware_minor", "H", "firmware version, minor"),
        ("firmware_patch", "H", "firmware version, patch"),
        ("build", "I", "the firmware's build (its commit's first 8 hex digits; 0 not set)"),
        ("serial", "Q", "the board's serial (the FPGA's 57-bit device DNA)"),
    ),
}


def _nested(entry: Field | tuple[str, Layout]) -> Layout | None:
    return entry[1] if len(entry) == 2 else None


def _codes(fields: Layout) -> str:
    return "".join(_codes(inner) if (inner := _nested(f)) is not None else str(f[1])
                   for f in fields)


def layout(msg_id: MessageId) -> Any:
    """The body of ``msg_id`` as a :mod:`construct` ``Struct`` — a readable, parsing and
    building description of the same layout (loaded on first use: the hot path does not
    need it)."""
    import construct as cs

    types = {"B": cs.Int8ul, "h": cs.Int16sl, "H": cs.Int16ul, "i": cs.Int32sl,
             "I": cs.Int32ul, "Q": cs.Int64ul, "f": cs.Float32l, "4s": cs.Bytes(4)}

    def build(fields: Layout) -> Any:
        return cs.Struct(*(
            f[0] / (build(inner) if (inner := _nested(f)) is not None else types[str(f[1])])
            for f in fields
        ))

    return build(BODIES[msg_id])


def body_format(msg_id: MessageId) -> str:
    """The body of ``msg_id`` as a little-endian :mod:`struct` format (the codec's)."""
    return "<" + _codes(BODIES[msg_id])


def content_length(msg_id: MessageId) -> int:
    """Frame content bytes of a catalogued message: ID, counter, ``{`` LEN body ``}``."""
    return 2 + 5 + 3 + struct.calcsize(body_format(msg_id))


_VALUE_INT = struct.Struct("<i")
_VALUE_FLOAT = struct.Struct("<f")
_VALUE_RAW = struct.Struct("<I")


def pack_value(value_type: int, value: int | float) -> bytes:
    """A parameter value's four wire bytes, as its type code says."""
    if value_type == ParamType.INT:
        return _VALUE_INT.pack(int(value))
    if value_type == ParamType.FLOAT:
        return _VALUE_FLOAT.pack(float(value))
    return _VALUE_RAW.pack(int(value) & 0xFFFFFFFF)


def unpack_value(value_type: int, raw: bytes) -> int | float:
    """A parameter value from its four wire bytes, as its type code says."""
    if value_type == ParamType.INT:
        return int(_VALUE_INT.unpack(raw)[0])
    if value_type == ParamType.FLOAT:
        return float(_VALUE_FLOAT.unpack(raw)[0])
    # An unknown type code still decodes, so the board can answer it with PN 4.
    return int(_VALUE_RAW.unpack(raw)[0])



# --- the messages -----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Catalogued(Event):
    msg_id: ClassVar[MessageId]

    def body_values(self) -> tuple[Any, ...]:
        """The values the wire body carries, in its layout's order (what the codec packs)."""
        raise NotImplementedError


@dataclass(frozen=True, slots=True)
class _ParamValue(_Catalogued):
    """The ``PS``/``PA`` body: which parameter, and a value of the given type."""

    param_id: int
    channel: int
    value_type: int  #: a :class:`~fpgalink.params.ParamType` code
    value: int | float
    counter: int | None = None

    def body_values(self) -> tuple[Any, ...]:
        return (self.param_id, self.channel, self.value_type,
                pack_value(self.value_type, self.value))


@dataclass(frozen=True, slots=True)
class ParamSet(_ParamValue):
    """``PS`` host → board: set a parameter."""

    msg_id: ClassVar[MessageId] = MessageId.PS


@dataclass(frozen=True, slots=True)
class ParamAck(_ParamValue):
    """``PA`` board → host: the value now in force (answers ``PS`` and ``PG``)."""

    msg_id: ClassVar[MessageId] = MessageId.PA


@dataclass(frozen=True, slots=True)
class ParamGet(_Catalogued):
    """``PG`` host → board: read a parameter."""

    msg_id: ClassVar[MessageId] = MessageId.PG
    param_id: int
    channel: int
    counter: int | None = None

    def body_values(self) -> tuple[Any, ...]:
        return (self.param_id, self.channel)


@dataclass(frozen=True, slots=True)
class ParamNack(_Catalogued):
    """``PN`` board → host: the request was refused; final."""

    msg_id: ClassVar[MessageId] = MessageId.PN
    param_id: int
    channel: int
    error: int  #: a :class:`NackReason` code
    counter: int | None = None

    def body_values(self) -> tuple[Any, ...]:
        return (self.param_id, self.channel, self.error)

    @property
    def reason(self) -> str:
        try:
            return NackReason(self.error).text
        except ValueError:
            return f"unknown refusal code {self.error}"


@dataclass(frozen=True, slots=True)
class References(_Catalogued):
    """``RV`` host → board: controller references (deg/s in speed control)."""

    msg_id: ClassVar[MessageId] = MessageId.RV
    ref_a: float
    ref_b: float
    counter: int | None = None

    def body_values(self) -> tuple[Any, ...]:
        return (self.ref_a, self.ref_b)


class ChannelTelemetry(NamedTuple):
    """One channel's part of a ``TM`` sample, in wire order."""

    position: int  #: encoder counts
    speed: float  #: deg/s
    current: float  #: A
    pwm: int  #: applied duty, −32760..32760, 0 while disabled
    reference: float
    flags: int  #: :class:`TelemetryFlags` bits

    @property
    def enabled(self) -> bool:
        return bool(self.flags & TelemetryFlags.ENABLE)

    @property
    def end_stop(self) -> bool:
        return bool(self.flags & TelemetryFlags.END_STOP)

    @property
    def saturated(self) -> bool:
        return bool(self.flags & TelemetryFlags.SATURATED)


@dataclass(frozen=True, slots=True)
class Telemetry(_Catalogued):
    """``TM`` board → host: one sample per timer period while ``GetDataPeriodical`` = 1."""

    msg_id: ClassVar[MessageId] = MessageId.TM
    t_us: int  #: board time in µs (wraps at 2³²)
    a: ChannelTelemetry
    b: ChannelTelemetry
    counter: int | None = None

    def body_values(self) -> tuple[Any, ...]:
        return (self.t_us, *self.a, *self.b)


@dataclass(frozen=True, slots=True)
class IdentityQuery(_Catalogued):
    """``IQ`` host → board: which protocol declaration, firmware and board are you? A board
    that knows it answers :class:`IdentityAnswer` with the same ``nonce``; a seed board
    counts it as an unknown message and answers nothing (:mod:`.identity`)."""

    msg_id: ClassVar[MessageId] = MessageId.IQ
    nonce: int
    counter: int | None = None

    def body_values(self) -> tuple[Any, ...]:
        return (self.nonce,)


@dataclass(frozen=True, slots=True)
class IdentityAnswer(_Catalogued):
    """``IA`` board → host: the answer to :class:`IdentityQuery`."""

    msg_id: ClassVar[MessageId] = MessageId.IA
    nonce: int
    declarations: int  #: the declaration hash (:func:`.identity.declarations_hash`)
    firmware_major: int
    firmware_minor: int
    firmware_patch: int
    build: int  #: 0: not set
    serial: int
    counter: int | None = None

    def body_values(self) -> tuple[Any, ...]:
        return (self.nonce, self.declarations, self.firmware_major, self.firmware_minor,
                self.firmware_patch, self.build, self.serial)


Message = (ParamSet | ParamAck | ParamGet | ParamNack | References | Telemetry | IdentityQuery
           | IdentityAnswer)
#: Every typed message, once: what a sender may send as itself (each class's ``msg_id``
#: says who sends it), and what :func:`.codec.encode_message` encodes.
MESSAGE_TYPES: tuple[type[Message], ...] = (
    ParamSet, ParamAck, ParamGet, ParamNack, References, Telemetry, IdentityQuery,
    IdentityAnswer)

Parsed = Message | CountedMessage | DirectCommand | Malformed
