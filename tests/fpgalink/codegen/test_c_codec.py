"""The generated C codec against the Python codec, byte for byte: every message type with
random fields, every parameter's checks, framing with escapes and overflows, the deframer
and the parser on garbage, the wire CRC's rule — and 100,000 random streams in one batch
through the C (tests/support/ccodec_harness.c)."""

from __future__ import annotations

import math
import os
import random
import shutil
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgaemu.firmware import Firmware
from fpgalink.codegen import declarations_digest, generate_c
from fpgalink.protocol import (
    PARAMETERS,
    Alive,
    ChannelTelemetry,
    CountedMessage,
    Disable,
    Enable,
    FrameDecoder,
    FrameTooLong,
    LocalProtocolError,
    Malformed,
    MalformedReason,
    MessageId,
    NackReason,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    ParamType,
    References,
    Scope,
    Telemetry,
    encode_frame,
    encode_message,
    float32,
    parse_content,
)
from fpgalink.protocol.catalogue import BODIES, IdentityAnswer, IdentityQuery, Message, Parsed
from fpgalink.protocol.crc import WIRE_CRC_PARAM, BoardWireCrc, append_crc
from fpgalink.protocol.messages import Binary, Text, encode_body, encode_counted
from tests.support.ccodec import c_codec, why_unavailable

_missing = why_unavailable()
if _missing is not None and os.environ.get("FPGALINK_REQUIRE_CC") == "1":
    raise RuntimeError(f"the C codec must be tested here (FPGALINK_REQUIRE_CC=1): {_missing}")
pytestmark = [pytest.mark.skipif(_missing is not None, reason=f"C codec: {_missing}"),
              pytest.mark.timeout(300)]

STREAMS = 100_000
_KIND_NAMES = ["MALFORMED", "COUNTED", "RE", "RD", "E", *(m.name for m in BODIES)]
_TYPED = {ParamSet: "PS", ParamAck: "PA", ParamGet: "PG", ParamNack: "PN",
          References: "RV", Telemetry: "TM", IdentityQuery: "IQ", IdentityAnswer: "IA"}
_IA_FIELDS = ("nonce", "declarations", "firmware_major", "firmware_minor", "firmware_patch",
              "build", "serial")


@pytest.fixture(scope="module")
def codec() -> tuple[Any, Any]:
    return c_codec()


def kind_code(name: str) -> int:
    return _KIND_NAMES.index(name)


# --- generating and building -----------------------------------------------------------------


def test_generate_then_make_builds_freestanding_and_passes_its_golden_vectors(
        tmp_path: Path) -> None:
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "fpgalink.codegen", "c", str(out)],
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    built = subprocess.run(["make", "-C", str(out), "all", "check"], capture_output=True,
                           text=True, timeout=300, check=False)
    assert built.returncode == 0, built.stdout + built.stderr
    # the strict flags were the ones used, and the codec linked with nothing but itself
    assert "-std=c99 -Wall -Wextra -Werror" in built.stdout and "-ffreestanding" in built.stdout
    assert "-nostdlib -Wl,--no-undefined" in built.stdout
    assert (out / "libfpgalink_protocol.so").exists()
    assert f"passed: 0 failure(s), declarations {declarations_digest()}" in built.stdout
    assert built.stdout.count("ok   ") == 1 + 9  # the CRC check value and nine vectors


def test_the_cli_writes_the_same_files(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "fpgalink", "codegen", "c", str(tmp_path)],
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    for generated in generate_c():
        assert (tmp_path / generated.name).read_text(encoding="utf-8") == generated.text


def test_the_header_declares_the_catalogue(codec: tuple[Any, Any]) -> None:
    ffi, lib = codec
    assert ffi.sizeof(ffi.typeof(lib.fl_params)) == len(PARAMETERS) * ffi.sizeof(
        "fl_param_info")
    for index, param in enumerate(PARAMETERS):
        entry = lib.fl_params[index]
        assert (entry.id, ffi.string(entry.name).decode(), entry.scope, entry.type) == (
            param.id, param.name, int(param.scope), int(param.type))
        assert ffi.string(entry.unit).decode() == param.unit
        if param.type is ParamType.INT:
            assert entry.power_up.i == param.default
        else:
            assert entry.power_up.f == float32(param.default)
    # the kinds fl_parse answers, numbered as the harness's records say
    assert [getattr(lib, f"FL_MSG_{name}") for name in _KIND_NAMES] == list(
        range(len(_KIND_NAMES)))
    assert [getattr(lib, f"FL_MALFORMED_{r.name}") for r in MalformedReason] == list(
        range(1, len(MalformedReason) + 1))


# --- encoding every message --------------------------------------------------------------------

u8 = st.integers(0, 255)
i16 = st.integers(-(2**15), 2**15 - 1)
i32 = st.integers(-(2**31), 2**31 - 1)
u16 = st.integers(0, 2**16 - 1)
u32 = st.integers(0, 2**32 - 1)
u64 = st.integers(0, 2**64 - 1)
counters = st.integers(0, 2**32 - 1)
f32 = st.floats(width=32, allow_nan=False)
channel_tm = st.builds(ChannelTelemetry, i32, f32, f32, i16, f32, u8)
param_values = st.one_of(
    st.tuples(st.just(1), i32), st.tuples(st.just(2), f32),
    st.tuples(st.integers(3, 255) | st.just(0), u32))
messages = st.one_of(
    st.builds(lambda p, c, tv: ParamSet(p, c, tv[0], tv[1]), u8, u8, param_values),
    st.builds(lambda p, c, tv: ParamAck(p, c, tv[0], tv[1]), u8, u8, param_values),
    st.builds(ParamGet, u8, u8), st.builds(ParamNack, u8, u8, u8),
    st.builds(References, st.floats(width=32), st.floats(width=32)),
    st.builds(Telemetry, u32, channel_tm, channel_tm),
    st.builds(IdentityQuery, u32),
    st.builds(IdentityAnswer, u32, u64, u16, u16, u16, u32, u64))


def _fill(ffi: Any, message: Message) -> Any:
    name = _TYPED[type(message)].lower()
    body = ffi.new(f"fl_{name}_t *")
    if isinstance(message, ParamSet | ParamAck):
        body.param_id, body.channel, body.value_type = (message.param_id, message.channel,
                                                        message.value_type)
        if message.value_type == ParamType.FLOAT:
            body.value.f = message.value
        elif message.value_type == ParamType.INT:
            body.value.i = message.value
        else:
            body.value.raw = message.value
    elif isinstance(message, ParamGet):
        body.param_id, body.channel = message.param_id, message.channel
    elif isinstance(message, ParamNack):
        body.param_id, body.channel, body.error = message.param_id, message.channel, \
            message.error
    elif isinstance(message, References):
        body.ref_a, body.ref_b = message.ref_a, message.ref_b
    elif isinstance(message, IdentityQuery):
        body.nonce = message.nonce
    elif isinstance(message, IdentityAnswer):
        for field in _IA_FIELDS:
            setattr(body, field, getattr(message, field))
    else:
        assert isinstance(message, Telemetry)
        body.t_us = message.t_us
        for side, values in (("a", message.a), ("b", message.b)):
            channel = getattr(body, side)
            for field, value in zip(ChannelTelemetry._fields, values, strict=True):
                setattr(channel, field, value)
    return body


@given(messages, counters)
def test_every_message_encodes_as_the_python_codec_does(message: Message, counter: int) -> None:
    ffi, lib = c_codec()
    name = _TYPED[type(message)].lower()
    out = ffi.new("uint8_t[]", 200)
    length = getattr(lib, f"fl_encode_{name}")(out, counter, _fill(ffi, message))
    try:
        expected = encode_message(message, counter)
    except LocalProtocolError:
        # only a non-finite reference is refused, on both sides
        assert isinstance(message, References) and length == 0
        return
    assert bytes(ffi.buffer(out, length)) == expected


def _c_fields(ffi: Any, parsed: Any, kind: str) -> tuple[Any, ...]:
    body = getattr(parsed.body, kind.lower())
    if kind in ("PS", "PA"):
        return (body.param_id, body.channel, body.value_type, body.value.raw)
    if kind == "PG":
        return (body.param_id, body.channel)
    if kind == "PN":
        return (body.param_id, body.channel, body.error)
    if kind == "RV":
        return _bits(body.ref_a, body.ref_b)
    if kind == "IQ":
        return (body.nonce,)
    if kind == "IA":
        return tuple(getattr(body, field) for field in _IA_FIELDS)
    return (body.t_us, *(v for side in (body.a, body.b) for v in (
        side.position, *_bits(side.speed, side.current), side.pwm, *_bits(side.reference),
        side.flags)))


def _bits(*values: float) -> tuple[int, ...]:
    return tuple(struct.unpack("<I", struct.pack("<f", v))[0] if not math.isnan(v) else -1
                 for v in values)


def _python_fields(message: Parsed) -> tuple[Any, ...]:
    if isinstance(message, ParamSet | ParamAck):
        raw = (struct.unpack("<I", struct.pack("<f", message.value))[0]
               if message.value_type == ParamType.FLOAT and not math.isnan(message.value)
               else -1 if message.value_type == ParamType.FLOAT
               else int(message.value) & 0xFFFF_FFFF)
        return (message.param_id, message.channel, message.value_type, raw)
    if isinstance(message, ParamGet):
        return (message.param_id, message.channel)
    if isinstance(message, ParamNack):
        return (message.param_id, message.channel, message.error)
    if isinstance(message, References):
        return _bits(message.ref_a, message.ref_b)
    if isinstance(message, IdentityQuery):
        return (message.nonce,)
    if isinstance(message, IdentityAnswer):
        return tuple(getattr(message, field) for field in _IA_FIELDS)
    assert isinstance(message, Telemetry)
    return (message.t_us, *(v for side in (message.a, message.b) for v in (
        side.position, *_bits(side.speed, side.current), side.pwm, *_bits(side.reference),
        side.flags)))


def _compare_parse(content: bytes) -> None:
    ffi, lib = c_codec()
    parsed = ffi.new("fl_message *")
    kind = lib.fl_parse(content, len(content), parsed)
    expected = parse_content(content)
    if isinstance(expected, Malformed):
        assert (kind, parsed.malformed) == (
            0, list(MalformedReason).index(expected.reason) + 1), (content, expected)
    elif isinstance(expected, CountedMessage):
        assert (_KIND_NAMES[kind], parsed.counter, parsed.items) == (
            "COUNTED", expected.counter, len(expected.items)), content
        assert struct.pack("<H", parsed.id).decode("latin-1") == expected.msg_id
    elif isinstance(expected, Enable | Disable | Alive):
        assert _KIND_NAMES[kind] == expected.msg_id.name
    else:
        assert isinstance(expected, ParamSet | ParamAck | ParamGet | ParamNack | References
                          | Telemetry | IdentityQuery | IdentityAnswer)
        name = _TYPED[type(expected)]
        assert (_KIND_NAMES[kind], parsed.counter) == (name, expected.counter), content
        fields = _c_fields(ffi, parsed, name)
        if isinstance(expected, ParamSet | ParamAck) and expected.value_type != ParamType.FLOAT:
            assert fields == _python_fields(expected)
        else:
            # a NaN's payload is not compared (Python's float keeps no float32 payload)
            assert fields == _python_fields(expected) or any(
                f == -1 for f in _python_fields(expected))


@given(messages, counters)
def test_every_encoded_message_parses_as_in_python(message: Message, counter: int) -> None:
    try:
        content = encode_message(message, counter)
    except LocalProtocolError:
        return
    _compare_parse(content)


special_bytes = st.sampled_from(b"SP\\{}0123456789PSPGPAPNRVTMREDE\x00\x07\xff")
contents = st.one_of(
    st.binary(max_size=60),
    st.lists(special_bytes, max_size=40).map(bytes),
    st.builds(lambda msg_id, counter, items: encode_counted(msg_id, counter, encode_body(items)),
              st.sampled_from([b"PS", b"PG", b"PA", b"PN", b"RV", b"TM", b"IQ", b"IA", b"ZZ",
                               b"A9", b"E1", b"RE", b"a!"]),
              counters,
              st.lists(st.one_of(
                  st.builds(Binary, st.binary(max_size=45)),
                  st.builds(Text, st.binary(max_size=8).filter(
                      lambda b: b"{" not in b and b"}" not in b))), max_size=3)),
)


@given(contents, st.data())
def test_any_content_parses_as_in_python(content: bytes, data: st.DataObject) -> None:
    _compare_parse(content)
    if content:  # and damaged: one byte changed
        at = data.draw(st.integers(0, len(content) - 1))
        _compare_parse(content[:at] + bytes((data.draw(u8),)) + content[at + 1:])


# --- framing --------------------------------------------------------------------------------


@given(st.one_of(st.binary(max_size=210), st.lists(special_bytes, max_size=210).map(bytes)))
def test_framing_escapes_and_the_limit_as_in_python(content: bytes) -> None:
    ffi, lib = c_codec()
    wire = ffi.new("uint8_t[]", 2 * len(content) + 2)
    framing = ffi.new("fl_framing *", [0x53, 0x50, 0x5C, 200])  # fl_default_framing's value
    length = lib.fl_frame(framing, content, len(content), wire, len(wire))
    try:
        expected = encode_frame(content)
    except FrameTooLong:
        assert length == 0
        return
    assert bytes(ffi.buffer(wire, length)) == expected
    # one byte short of room: refused, never overrun
    assert lib.fl_frame(framing, content, len(content), wire, length - 1) == 0


def _stream_records(streams: list[bytes]) -> tuple[bytes, bytes]:
    """(the C's records, the Python codec's records) for the same streams."""
    ffi, lib = c_codec()
    data = b"".join(streams)
    ends, total = [], 0
    for stream in streams:
        total += len(stream)
        ends.append(total)
    capacity = 37 * len(streams) + 12 * (len(data) // 2 + 1)
    out = ffi.new("uint8_t[]", capacity)
    written = lib.harness_streams(data, ends, len(streams), out, capacity)
    assert written > 0
    return bytes(ffi.buffer(out, written)), b"".join(map(_python_records, streams))


_STAT_FIELDS = ("frames", "frame_bytes", "escape_bytes", "dropped_bytes", "noise_bytes",
                "restarts", "overflows", "bytes_fed")
#: One decoder for every stream (building one costs more than decoding a short stream): each
#: stream's counts are its deltas, and a reset after it forgets its unfinished frame.
_DECODER = FrameDecoder()


def _python_records(stream: bytes) -> bytes:
    decoder = _DECODER
    before = [getattr(decoder.stats, f) for f in _STAT_FIELDS]
    records = []
    for item in decoder.feed(stream):
        if type(item) is not bytes:
            continue
        message = parse_content(item)
        counter, items, msg_id, again = 0, 0, 0, 0
        if isinstance(message, Malformed):
            kind, reason = 0, list(MalformedReason).index(message.reason) + 1
        else:
            reason = 0
            if isinstance(message, CountedMessage):
                kind, counter, items = 1, message.counter or 0, len(message.items)
                msg_id = struct.unpack("<H", message.msg_id.encode("latin-1"))[0]
            elif isinstance(message, Enable | Disable | Alive):
                kind = kind_code(message.msg_id.name)
            else:
                assert isinstance(message, ParamSet | ParamAck | ParamGet | ParamNack
                                  | References | Telemetry | IdentityQuery | IdentityAnswer)
                kind = kind_code(_TYPED[type(message)])
                counter = message.counter or 0
                refused = isinstance(message, References) and not (
                    math.isfinite(message.ref_a) and math.isfinite(message.ref_b))
                again = 2 if refused else 1
        records.append(struct.pack("<cBBIBHBB", b"F", kind, reason, counter, items, msg_id,
                                   len(item), again))
    counts = [getattr(decoder.stats, f) - b for f, b in zip(_STAT_FIELDS, before, strict=True)]
    records.append(struct.pack("<c9I", b"S", *counts, decoder.pending))
    decoder.reset()
    return b"".join(records)


def _first_difference(streams: list[bytes]) -> str:
    for stream in streams:
        c_records, py_records = _stream_records([stream])
        if c_records != py_records:
            return f"stream {stream!r}: C {c_records.hex()} Python {py_records.hex()}"
    return "no single stream differs"


def _framed(message: Message, counter: int) -> bytes:
    try:
        return encode_frame(encode_message(message, counter))
    except LocalProtocolError:  # a non-finite reference is never sent
        return b""


@given(st.lists(st.one_of(
    st.binary(max_size=80), st.lists(special_bytes, max_size=80).map(bytes),
    st.builds(_framed, messages, counters)), min_size=1, max_size=6).map(b"".join))
def test_garbage_streams_deframe_and_parse_as_in_python(stream: bytes) -> None:
    c_records, py_records = _stream_records([stream])
    assert c_records == py_records


# --- 100,000 random streams ----------------------------------------------------------------


def _pieces(rng: random.Random) -> list[bytes]:
    """Wire pieces streams are made of: every message type framed (plain and with the CRC),
    unknown and malformed counted messages, direct commands, frames at and past the content
    limit, escapes galore, noise."""
    pieces: list[bytes] = [b"SREP", b"SRDP", b"SEP", b"S", b"P", b"\\", b"SP", b"S\\SP"]

    def f32() -> float:
        value: float = rng.choice([0.0, -0.0, 1.5, -45.0, 1e30, float("inf"), float("nan"),
                           rng.uniform(-1e4, 1e4), struct.unpack("<f", rng.randbytes(4))[0]])
        return value

    def tm_channel() -> ChannelTelemetry:
        return ChannelTelemetry(rng.randint(-(2**31), 2**31 - 1), f32(), f32(),
                                rng.randint(-32768, 32767), f32(), rng.randint(0, 255))

    for _ in range(1500):
        counter = rng.randrange(100_000)
        kind = rng.randrange(9)
        message: Message
        if kind == 0:
            message = ParamSet(rng.randrange(256), rng.randrange(4), rng.choice([1, 2, 7]),
                               rng.randint(-5, 40000))
        elif kind == 1:
            message = ParamAck(rng.randrange(256), rng.randrange(4), 2, f32())
        elif kind == 2:
            message = ParamGet(rng.randrange(256), rng.randrange(4))
        elif kind == 3:
            message = ParamNack(rng.randrange(256), rng.randrange(256), rng.randrange(5))
        elif kind == 4:
            message = References(rng.uniform(-90, 90), rng.choice([0.0, 83.5, -1e-3]))
        elif kind == 5:
            message = IdentityQuery(rng.randrange(2**32))
        elif kind == 6:
            message = IdentityAnswer(rng.randrange(2**32), rng.randrange(2**64),
                                     rng.randrange(2**16), rng.randrange(2**16),
                                     rng.randrange(2**16), rng.randrange(2**32),
                                     rng.randrange(2**64))
        else:
            message = Telemetry(rng.randrange(2**32), tm_channel(), tm_channel())
        content = encode_message(message, counter)
        pieces.append(encode_frame(content))
        pieces.append(encode_frame(append_crc(content)))
    for _ in range(400):
        items = [Binary(rng.randbytes(rng.randrange(30))) if rng.random() < 0.5
                 else Text(bytes(rng.choice(b"abcSP\\09 ") for _ in range(rng.randrange(6))))
                 for _ in range(rng.randrange(4))]
        msg_id = rng.choice([b"ZZ", b"PS", b"TM", b"Q1", b"E7", b"RE", b"p!", b"\x00\x00"])
        pieces.append(encode_frame(msg_id + b"%05d" % rng.randrange(100_000)
                                   + encode_body(items)))
    for size in (198, 199, 200, 201, 202, 260):
        content = bytes(rng.choice(b"xSP\\{") for _ in range(size))
        escaped = b"S" + b"".join(b"\\" + bytes((b,)) if b in b"SP\\" else bytes((b,))
                                  for b in content) + b"P"
        pieces.append(escaped)
    for _ in range(300):
        pieces.append(bytes(rng.choice(b"SP\\{}0123456789TMPSRVEx\x00\xff")
                            for _ in range(rng.randrange(1, 40))))
    return pieces


def _random_streams(count: int, seed: int) -> list[bytes]:
    rng = random.Random(seed)
    pieces = _pieces(rng)
    streams = []
    for _ in range(count):
        stream = bytearray(b"".join(rng.choices(pieces, k=rng.randint(1, 5))))
        for _ in range(rng.choice((0, 0, 1, 1, 2, 3))):  # damage: a byte changed, lost, added
            at = rng.randrange(len(stream)) if stream else 0
            what = rng.randrange(3)
            if what == 0 and stream:
                stream[at] = rng.choice(b"SP\\{}\x00\xff0" + bytes((rng.randrange(256),)))
            elif what == 1 and stream:
                del stream[at]
            else:
                stream.insert(at, rng.choice(b"SP\\{}x"))
        if rng.random() < 0.2 and stream:
            del stream[rng.randrange(len(stream)):]  # cut short: an unfinished frame
        streams.append(bytes(stream))
    return streams


def test_100k_random_streams_give_the_same_frames_messages_and_counts() -> None:
    streams = _random_streams(STREAMS, seed=29)
    c_records, py_records = _stream_records(streams)
    if c_records != py_records:
        pytest.fail(_first_difference(streams))
    # the streams covered what they were made for
    frames = py_records.count(b"F")
    assert frames > STREAMS and py_records.count(b"S") >= STREAMS
    for kind in _KIND_NAMES:
        marker = struct.pack("<cB", b"F", kind_code(kind))
        assert marker in py_records, kind


# --- parameters and the CRC rule -------------------------------------------------------------

_PYTHON_FIRMWARE = Firmware()


def _python_check(param_id: int, channel: int, value_type: int, raw: int) -> int:
    """The PN code the Python firmware gives this PS (0: accepted)."""
    param = _PYTHON_FIRMWARE.parameters.get(param_id)
    if param is None:
        return int(NackReason.UNKNOWN_ID)
    if value_type == ParamType.INT:
        value: int | float = struct.unpack("<i", struct.pack("<I", raw))[0]
    elif value_type == ParamType.FLOAT:
        value = struct.unpack("<f", struct.pack("<I", raw))[0]
    else:
        value = raw
    return int(_PYTHON_FIRMWARE._check(param, channel, value_type, value) or 0)


_interesting_raw = st.one_of(
    u32, st.integers(-3, 70000).map(lambda v: v & 0xFFFF_FFFF),
    st.floats(width=32).map(lambda f: struct.unpack("<I", struct.pack("<f", f))[0]),
    st.sampled_from([0x8000_0000, 0x7F80_0000, 0xFF80_0000, 0x7FC0_0000, 0x0000_0001,
                     0xFFFF_FFFF, 0x3F80_0000]))


@given(st.integers(0, 13), st.integers(0, 4), st.integers(0, 3), _interesting_raw)
def test_every_parameter_check_answers_as_the_python_firmware(
        param_id: int, channel: int, value_type: int, raw: int) -> None:
    _, lib = c_codec()
    assert lib.harness_check_set(param_id, channel, value_type, raw) == _python_check(
        param_id, channel, value_type, raw)


@pytest.mark.parametrize("param", PARAMETERS, ids=lambda p: p.name)
def test_each_parameters_range_edges(param: Any) -> None:
    _, lib = c_codec()
    channel = 0 if param.scope is Scope.BOARD else 2
    if param.type is ParamType.INT:
        candidates = [int(param.minimum) - 1, int(param.minimum), int(param.maximum),
                      int(param.maximum) + 1, 0, -1, 1, 2**31 - 1, -(2**31)]
        raws = [v & 0xFFFF_FFFF for v in candidates if -(2**31) <= v < 2**31]
    else:
        floats = [0.0, -0.0, 1e-45, -1e-45, 1.0, 3.4e38, -1.0, math.inf, -math.inf, math.nan]
        raws = [struct.unpack("<I", struct.pack("<f", v))[0] for v in floats]
    for raw in raws:
        assert lib.harness_check_set(param.id, channel, int(param.type), raw) == _python_check(
            param.id, channel, int(param.type), raw), (param.name, hex(raw))


handshakes = st.builds(
    lambda m, c: encode_message(m, c),
    st.one_of(st.builds(ParamSet, st.just(WIRE_CRC_PARAM), st.integers(0, 3),
                        st.sampled_from([1, 2]), st.integers(0, 2)),
              st.builds(ParamGet, st.just(WIRE_CRC_PARAM), st.integers(0, 3)),
              st.builds(ParamGet, u8, u8)),
    counters)


@given(st.one_of(handshakes, handshakes.map(append_crc), contents, contents.map(append_crc)),
       st.booleans(), st.integers(-1, 30))
def test_the_boards_crc_rule_is_the_same_in_c(content: bytes, crc_on: bool,
                                              damage: int) -> None:
    _, lib = c_codec()
    if 0 <= damage < len(content):
        content = content[:damage] + bytes((content[damage] ^ 0x21,)) + content[damage + 1:]
    board = BoardWireCrc()
    board.on = crc_on
    expected = board.receive(content)
    got = lib.fl_crc_board_receive(crc_on, content, len(content))
    assert got == (-1 if expected is None else len(expected))


def test_the_crc_matches_python_on_random_data() -> None:
    from fpgalink.protocol.crc import crc16

    _, lib = c_codec()
    rng = random.Random(5)
    for n in range(300):
        data = rng.randbytes(n)
        assert lib.fl_crc16(data, n) == crc16(data)


def test_a_message_id_macro_per_catalogue_id() -> None:
    header = next(g.text for g in generate_c() if g.name.endswith(".h"))
    for msg_id in MessageId:
        assert f"#define FL_ID_{msg_id.name} " in header
