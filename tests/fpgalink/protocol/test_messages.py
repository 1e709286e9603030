"""SPEC §4: direct commands, counted messages, body items, the typed catalogue, golden vectors."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgalink import Connection, LocalProtocolError, Role, Telemetry
from fpgalink.protocol import (
    Alive,
    Binary,
    ChannelTelemetry,
    CountedMessage,
    Disable,
    Enable,
    Malformed,
    MalformedReason,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    References,
    Text,
    encode_message,
    parse_content,
)
from fpgalink.protocol.messages import MessageId, encode_body, encode_counted
from fpgalink.protocol.params import float32
from tests.support.wire import received, sent

# --- golden vectors: byte-exact, written out by hand ------------------------------------------


def test_golden_direct_commands() -> None:
    host = Connection()
    assert sent(Enable(), host) == b"SREP"
    assert sent(Disable(), host) == b"SRDP"
    assert sent(Alive(), role=Role.BOARD) == b"SEP"
    # Direct commands take no counter.
    assert host.next_counter == 0


def test_golden_param_set_kp_channel_a() -> None:
    # PS, counter 00000, one 7-byte section: id 8, channel 1 (A), type 2 (float), 7.11 as
    # float32 0x40E3851F little-endian. The ID itself is "P" "S": both are escaped.
    wire = sent(ParamSet(8, 1, 2, 7.11))
    assert wire == bytes.fromhex(
        "53" "5c50" "5c53" "3030303030" "7b" "07" "08" "01" "02" "1f85e340" "7d" "50"
    )


def test_golden_telemetry_with_escapes() -> None:
    # t_us = 0x005C5053: its bytes are S, P, backslash, 0 — each escaped on the wire.
    tm = Telemetry(
        0x005C5053,
        ChannelTelemetry(1000, 45.0, 1.5, 16380, 45.0, 1),
        ChannelTelemetry(-80, -2.5, 0.25, -100, 0.0, 3),
    )
    wire = sent(tm, role=Role.BOARD)
    expected = bytes.fromhex(
        "53" "544d" "3030303030" "7b" "2a"  # S, "TM", "00000", "{", LEN 42
        "5c53" "5c50" "5c5c" "00"  # t_us: S P \ 0, escaped
        "e8030000" "00003442" "0000c03f" "fc3f" "00003442" "01"  # channel A
        "b0ffffff" "000020c0" "0000803e" "9cff" "00000000" "03"  # channel B
        "7d" "50"
    )
    assert wire == expected
    assert len(encode_message(tm, 0)) == 52  # SPEC: a TM frame is 52 content bytes
    assert received(wire) == [Telemetry(tm.t_us, tm.a, tm.b, 0)]


# --- round trips ------------------------------------------------------------------------------

f32 = st.floats(width=32, allow_nan=False)
finite32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
i32 = st.integers(-(2**31), 2**31 - 1)
u8 = st.integers(0, 255)
channels = st.builds(
    ChannelTelemetry, i32, f32, f32, st.integers(-32768, 32767), f32, u8
)
messages = st.one_of(
    st.builds(ParamSet, u8, u8, st.just(1), i32),
    st.builds(ParamSet, u8, u8, st.just(2), f32),
    st.builds(ParamAck, u8, u8, st.just(1), i32),
    st.builds(ParamAck, u8, u8, st.just(2), f32),
    st.builds(ParamGet, u8, u8),
    st.builds(ParamNack, u8, u8, u8),
    st.builds(References, finite32, finite32),
    st.builds(Telemetry, st.integers(0, 2**32 - 1), channels, channels),
)


def with_counter(message: object, counter: int) -> object:
    import dataclasses

    return dataclasses.replace(message, counter=counter)  # type: ignore[type-var]


@given(messages, st.integers(0, 99_999))
def test_catalogue_round_trip(message: object, counter: int) -> None:
    content = encode_message(message, counter)  # type: ignore[arg-type]
    assert parse_content(content) == with_counter(message, counter)


def test_float32_rounding_is_what_comes_back() -> None:
    got = parse_content(encode_message(References(0.1, math.pi), 7))
    assert isinstance(got, References)
    assert got.ref_a == float32(0.1) and got.ref_b == float32(math.pi)


id_chars = st.sampled_from("ABCDFGHIJKLMNOPQRSTUVWXYZ0123456789")
free_ids = st.builds(lambda a, b: a + b, id_chars.filter(lambda c: c != "E"), id_chars).filter(
    lambda i: MessageId.lookup(i) is None  # neither direct nor catalogued
)
items = st.lists(
    st.one_of(
        st.binary(min_size=1, max_size=20).filter(lambda b: b"{" not in b and b"}" not in b)
        .map(Text),
        st.binary(max_size=254).map(Binary),
    ),
    max_size=4,
)


def merge_text(seq: list[Text | Binary]) -> tuple[Text | Binary, ...]:
    # Adjacent text items are one text item on the wire.
    out: list[Text | Binary] = []
    for item in seq:
        if out and isinstance(item, Text) and isinstance(out[-1], Text):
            out[-1] = Text(out[-1].data + item.data)
        else:
            out.append(item)
    return tuple(out)


@given(free_ids, st.integers(0, 99_999), items)
def test_unknown_ids_decode_generically(
    msg_id: str, counter: int, body: list[Text | Binary]
) -> None:
    content = encode_message(CountedMessage(msg_id, tuple(body)), counter)
    assert parse_content(content) == CountedMessage(msg_id, merge_text(body), counter)


def test_direct_commands_parse() -> None:
    assert parse_content(b"RE") == Enable()
    assert parse_content(b"RD") == Disable()
    assert parse_content(b"E") == Alive()


# --- malformed --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (b"", MalformedReason.EMPTY),
        (b"TM12", MalformedReason.TOO_SHORT),
        (b"t100001", MalformedReason.BAD_ID),
        (b"T!00001", MalformedReason.BAD_ID),
        (b"EX00001", MalformedReason.RESERVED_ID),
        (b"RE00001", MalformedReason.RESERVED_ID),
        (b"XY0a001", MalformedReason.BAD_COUNTER),
        (b"XY 0001", MalformedReason.BAD_COUNTER),
        (b"XY00001ab}", MalformedReason.STRAY_CLOSE),
        (b"XY00001{", MalformedReason.TRUNCATED_SECTION),
        (b"XY00001{\x05abc", MalformedReason.TRUNCATED_SECTION),
        (b"XY00001{\x02abc}", MalformedReason.UNCLOSED_SECTION),
        (b"XY00001{\xff" + b"x" * 255 + b"}", MalformedReason.RESERVED_LEN),
        (b"RV00001{\x08" + b"\x00" * 8 + b"}junk", MalformedReason.BAD_LAYOUT),
        (b"RV00001{\x04" + b"\x00" * 4 + b"}", MalformedReason.BAD_LAYOUT),
        (b"TM00001text", MalformedReason.BAD_LAYOUT),
        (b"PG00001{\x02\x01\x01}{\x00}", MalformedReason.BAD_LAYOUT),
    ],
)
def test_malformed_reasons(content: bytes, reason: MalformedReason) -> None:
    got = parse_content(content)
    assert isinstance(got, Malformed)
    assert got.reason is reason
    assert got.content == content


@given(st.binary(max_size=300))
def test_parse_never_raises(content: bytes) -> None:
    parse_content(content)


@given(messages, st.integers(0, 99_999), st.data())
def test_truncated_catalogue_messages_are_malformed(
    message: object, counter: int, data: st.DataObject
) -> None:
    content = encode_message(message, counter)  # type: ignore[arg-type]
    cut = data.draw(st.integers(0, len(content) - 1))
    assert isinstance(parse_content(content[:cut]), Malformed)


def test_encoding_refuses_what_cannot_travel() -> None:
    with pytest.raises(LocalProtocolError, match="reserved"):
        encode_message(CountedMessage("EX", ()), 0)
    with pytest.raises(LocalProtocolError, match="A-Z0-9"):
        encode_message(CountedMessage("x1", ()), 0)
    with pytest.raises(LocalProtocolError, match="254"):
        encode_body([Binary(b"x" * 255)])
    with pytest.raises(LocalProtocolError, match="cannot contain"):
        encode_body([Text(b"a{b")])
    with pytest.raises(LocalProtocolError):
        encode_message(ParamGet(256, 0), 0)
    with pytest.raises(LocalProtocolError, match="does not send"):
        Connection().send(Alive(), 0.0)
    with pytest.raises(LocalProtocolError, match="does not send"):
        Connection(role=Role.BOARD).send(ParamSet(1, 0, 1, 1), 0.0)


def test_counter_is_five_digits_and_wraps() -> None:
    assert encode_counted(b"XY", 99_999, b"") == b"XY99999"
    assert encode_counted(b"XY", 100_000, b"") == b"XY00000"
    conn = Connection(baud=None)
    for _ in range(99_999):  # the connection's own counter, through its public API
        conn.send(References(0, 0), 0.0)
    conn.data_to_send()
    assert conn.next_counter == 99_999
    first = sent(References(0, 0), conn)
    second = sent(References(0, 0), conn)
    assert b"99999" in first and b"00000" in second
    assert struct.calcsize("<ff") == 8


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_references_do_not_encode_but_still_decode(bad: float) -> None:
    # A host must never send one; a board must still make sense of one it receives.
    with pytest.raises(LocalProtocolError, match="finite"):
        encode_message(References(bad, 1.0), 0)
    raw = b"RV00003{\x08" + struct.pack("<ff", bad, 1.0) + b"}"
    got = parse_content(raw)
    assert isinstance(got, References) and got.ref_b == 1.0


def test_values_too_large_for_a_float32_do_not_encode() -> None:
    with pytest.raises(LocalProtocolError):
        encode_message(References(1e39, 0.0), 0)
    with pytest.raises(LocalProtocolError):
        encode_message(ParamSet(8, 1, 2, 1e39), 0)
