"""The wire, as SPEC §3–§5 define it: no I/O, no clock, no asyncio.

This package is the single home of the protocol. The host's :class:`~fpgalink.Connection`
stands on it, and so does the board emulator (``fpgaemu``): it is the only part of
``fpgalink`` that the emulator imports.

* :mod:`.framing` — ``S``/``P``/``\\`` framing: :func:`encode_frame` (:class:`FrameEncoder`),
  :class:`FrameDecoder`;
* :mod:`.messages` — wire IDs (:class:`MessageId`), direct commands, counted messages;
* :mod:`.catalogue` — the typed messages ``PS PG PA PN RV TM IQ IA`` and their layouts;
* :mod:`.codec` — contents to messages and back: :func:`parse_content`,
  :func:`encode_message` (:func:`encode_telemetry` for a ``TM`` from its fields);
* :mod:`.params` — the parameter table (ranges, types, power-up defaults);
* :mod:`.counter` — the sender's counter and the receiver's gap/duplicate tracker;
* :mod:`.wire` — 8N1 wire-time arithmetic and budgets;
* :mod:`.crc` — the optional wire CRC (CRC-16/CCITT-FALSE) and its handshake;
* :mod:`.framingerrors` — the counted framing errors a decoder reports (events);
* :mod:`.identity` — board identity (``IQ``/``IA``): the declaration hash, what a board
  says of itself, and the match, mismatch or seed-protocol judgement.

Names load from their submodule on first use, so importing one part of the protocol (the
wire arithmetic, say) does not import the rest.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fpgalink.protocol.exports import lazy_exports

#: public name → the submodule that defines it
_HOMES = {
    "AbortReason": "fpgalink.protocol.framingerrors",
    "Alive": "fpgalink.protocol.messages",
    "Binary": "fpgalink.protocol.messages",
    "COUNTER_MODULUS": "fpgalink.protocol.messages",
    "ChannelTelemetry": "fpgalink.protocol.catalogue",
    "CountedMessage": "fpgalink.protocol.messages",
    "CounterTracker": "fpgalink.protocol.counter",
    "CRC16": "fpgalink.protocol.crc",
    "CRC_BYTES": "fpgalink.protocol.crc",
    "CrcMismatch": "fpgalink.protocol.framingerrors",
    "WIRE_CRC_PARAM": "fpgalink.protocol.crc",
    "DEFAULT_FRAMING": "fpgalink.protocol.framing",
    "DirectCommand": "fpgalink.protocol.messages",
    "Disable": "fpgalink.protocol.messages",
    "Enable": "fpgalink.protocol.messages",
    "Event": "fpgalink.protocol.event",
    "FpgalinkError": "fpgalink.protocol.errors",
    "FLOAT32_MAX": "fpgalink.protocol.params",
    "FrameAborted": "fpgalink.protocol.framingerrors",
    "FrameDecoder": "fpgalink.protocol.framing",
    "FrameEncoder": "fpgalink.protocol.framing",
    "FrameTooLong": "fpgalink.protocol.framing",
    "Framing": "fpgalink.protocol.framing",
    "FramingError": "fpgalink.protocol.framingerrors",
    "FramingStats": "fpgalink.protocol.framing",
    "LocalProtocolError": "fpgalink.protocol.errors",
    "Malformed": "fpgalink.protocol.messages",
    "MalformedReason": "fpgalink.protocol.messages",
    "Message": "fpgalink.protocol.catalogue",
    "MessageId": "fpgalink.protocol.messages",
    "NackReason": "fpgalink.protocol.catalogue",
    "NoiseDropped": "fpgalink.protocol.framingerrors",
    "Observation": "fpgalink.protocol.counter",
    "PARAMETERS": "fpgalink.protocol.params",
    "Param": "fpgalink.protocol.params",
    "ParamAck": "fpgalink.protocol.catalogue",
    "ParamGet": "fpgalink.protocol.catalogue",
    "ParamNack": "fpgalink.protocol.catalogue",
    "ParamSet": "fpgalink.protocol.catalogue",
    "ParamType": "fpgalink.protocol.params",
    "ParameterError": "fpgalink.protocol.errors",
    "Parsed": "fpgalink.protocol.catalogue",
    "References": "fpgalink.protocol.catalogue",
    "Role": "fpgalink.protocol.messages",
    "Scope": "fpgalink.protocol.params",
    "SendCounter": "fpgalink.protocol.counter",
    "Telemetry": "fpgalink.protocol.catalogue",
    "TelemetryFlags": "fpgalink.protocol.catalogue",
    "Text": "fpgalink.protocol.messages",
    "UnknownParameter": "fpgalink.protocol.errors",
    "content_length": "fpgalink.protocol.catalogue",
    "encode_frame": "fpgalink.protocol.framing",
    "encode_message": "fpgalink.protocol.codec",
    "encode_telemetry": "fpgalink.protocol.codec",
    "float32": "fpgalink.protocol.params",
    "lookup": "fpgalink.protocol.params",
    "parse_content": "fpgalink.protocol.codec",
    "parse_contents": "fpgalink.protocol.codec",
    "parse_telemetry_run": "fpgalink.protocol.codec",
    "TELEMETRY_RUN_MIN": "fpgalink.protocol.codec",
    "resolve": "fpgalink.protocol.params",
    "BoardIdentity": "fpgalink.protocol.identity",
    "IdentityMatch": "fpgalink.protocol.identity",
    "IdentityMismatch": "fpgalink.protocol.identity",
    "IdentityProbe": "fpgalink.protocol.identity",
    "SEED_PROTOCOL": "fpgalink.protocol.identity",
    "compare_identity": "fpgalink.protocol.identity",
    "declarations_digest": "fpgalink.protocol.identity",
    "declarations_hash": "fpgalink.protocol.identity",
    "require_identity": "fpgalink.protocol.identity",
    "NOT_ASKED": "fpgalink.protocol.identity",
    "describe_identity": "fpgalink.protocol.identity",
    "identity_metadata": "fpgalink.protocol.identity",
    "IdentityAnswer": "fpgalink.protocol.catalogue",
    "IdentityQuery": "fpgalink.protocol.catalogue",
    "MESSAGE_TYPES": "fpgalink.protocol.catalogue",
}

if TYPE_CHECKING:
    from fpgalink.protocol.catalogue import (
        MESSAGE_TYPES,
        ChannelTelemetry,
        IdentityAnswer,
        IdentityQuery,
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
    )
    from fpgalink.protocol.codec import (
        TELEMETRY_RUN_MIN,
        encode_message,
        encode_telemetry,
        parse_content,
        parse_contents,
        parse_telemetry_run,
    )
    from fpgalink.protocol.counter import CounterTracker, Observation, SendCounter
    from fpgalink.protocol.crc import CRC16, CRC_BYTES, WIRE_CRC_PARAM
    from fpgalink.protocol.errors import (
        FpgalinkError,
        LocalProtocolError,
        ParameterError,
        UnknownParameter,
    )
    from fpgalink.protocol.event import Event
    from fpgalink.protocol.framing import (
        DEFAULT_FRAMING,
        FrameDecoder,
        FrameEncoder,
        FrameTooLong,
        Framing,
        FramingStats,
        encode_frame,
    )
    from fpgalink.protocol.framingerrors import (
        AbortReason,
        CrcMismatch,
        FrameAborted,
        FramingError,
        NoiseDropped,
    )
    from fpgalink.protocol.identity import (
        NOT_ASKED,
        SEED_PROTOCOL,
        BoardIdentity,
        IdentityMatch,
        IdentityMismatch,
        IdentityProbe,
        compare_identity,
        declarations_digest,
        declarations_hash,
        describe_identity,
        identity_metadata,
        require_identity,
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
        FLOAT32_MAX,
        PARAMETERS,
        Param,
        ParamType,
        Scope,
        float32,
        lookup,
        resolve,
    )


__getattr__ = lazy_exports(__name__, _HOMES)

__all__ = [
    "COUNTER_MODULUS",
    "CRC16",
    "CRC_BYTES",
    "DEFAULT_FRAMING",
    "FLOAT32_MAX",
    "MESSAGE_TYPES",
    "NOT_ASKED",
    "PARAMETERS",
    "SEED_PROTOCOL",
    "TELEMETRY_RUN_MIN",
    "WIRE_CRC_PARAM",
    "AbortReason",
    "Alive",
    "Binary",
    "BoardIdentity",
    "ChannelTelemetry",
    "CountedMessage",
    "CounterTracker",
    "CrcMismatch",
    "DirectCommand",
    "Disable",
    "Enable",
    "Event",
    "FpgalinkError",
    "FrameAborted",
    "FrameDecoder",
    "FrameEncoder",
    "FrameTooLong",
    "Framing",
    "FramingError",
    "FramingStats",
    "IdentityAnswer",
    "IdentityMatch",
    "IdentityMismatch",
    "IdentityProbe",
    "IdentityQuery",
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
    "compare_identity",
    "content_length",
    "declarations_digest",
    "declarations_hash",
    "describe_identity",
    "encode_frame",
    "encode_message",
    "encode_telemetry",
    "float32",
    "identity_metadata",
    "lookup",
    "parse_content",
    "parse_contents",
    "parse_telemetry_run",
    "require_identity",
    "resolve",
]
