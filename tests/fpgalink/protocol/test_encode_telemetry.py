"""``encode_telemetry(counter, t_us, a, b)``: the board's 1 kHz TM packed from its fields must be
byte for byte ``encode_message(Telemetry(t_us, a, b), counter)``, refuse what that refuses,
and parse back to the same sample."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgalink.protocol import (
    COUNTER_MODULUS,
    ChannelTelemetry,
    LocalProtocolError,
    Telemetry,
    encode_message,
    encode_telemetry,
    parse_content,
)

i32 = st.integers(-(2**31), 2**31 - 1)
u32 = st.integers(0, 2**32 - 1)
#: the applied duty's range (±100 %), inside the field's i16
pwm = st.integers(-32760, 32760)
#: the three defined bits, and any other u8 the field can carry
flags = st.integers(0, 7) | st.integers(0, 255)
#: in range, and past the modulus (the counter is taken modulo 100000)
counters = st.integers(0, COUNTER_MODULUS - 1) | st.integers(COUNTER_MODULUS, 10**12)
#: float32-representable, NaN and the infinities included: these always pack
any_f32 = st.floats(width=32)
#: float32-representable numbers that compare equal to themselves after a round trip
f32 = st.floats(width=32, allow_nan=False)
#: any finite double: past float32's range both encoders must refuse alike
finite = st.floats(allow_nan=False, allow_infinity=False)


def channels(floats: st.SearchStrategy[float]) -> st.SearchStrategy[ChannelTelemetry]:
    return st.builds(ChannelTelemetry, i32, floats, floats, pwm, floats, flags)


def outcome(encode: Callable[[], bytes]) -> bytes | str:
    """The bytes ``encode()`` returns, or ``"refused"`` for a ``LocalProtocolError``."""
    try:
        return encode()
    except LocalProtocolError:
        return "refused"


@given(counters, u32, channels(any_f32), channels(any_f32))
def test_same_bytes_as_encode_message(
    counter: int, t_us: int, a: ChannelTelemetry, b: ChannelTelemetry
) -> None:
    """Packed from its fields, a TM is the exact content encode_message gives: the board's fast
    path must not change a byte the host sees."""
    assert encode_telemetry(counter, t_us, a, b) == encode_message(Telemetry(t_us, a, b), counter)


@given(counters, u32, channels(finite), channels(finite))
def test_any_finite_float_gives_the_same_outcome(
    counter: int, t_us: int, a: ChannelTelemetry, b: ChannelTelemetry
) -> None:
    """For any finite double, both encoders give the same bytes or both refuse: a float past
    float32's range is refused on the fast path too, not packed differently."""
    assert outcome(lambda: encode_telemetry(counter, t_us, a, b)) == outcome(
        lambda: encode_message(Telemetry(t_us, a, b), counter))


@given(st.integers(0, COUNTER_MODULUS - 1), st.integers(1, 10**7), u32,
       channels(any_f32), channels(any_f32))
def test_counter_is_taken_modulo_100000(
    counter: int, turns: int, t_us: int, a: ChannelTelemetry, b: ChannelTelemetry
) -> None:
    """A counter past 99999 is sent as its value modulo 100000: the sender's counter wraps."""
    assert encode_telemetry(counter + turns * COUNTER_MODULUS, t_us, a, b) == encode_telemetry(
        counter, t_us, a, b)


@given(counters, u32, channels(f32), channels(f32))
def test_parses_back_to_the_same_telemetry(
    counter: int, t_us: int, a: ChannelTelemetry, b: ChannelTelemetry
) -> None:
    """The content parses back to an equal Telemetry (float32 values exactly): what the
    emulator sends is what the host reads."""
    got = parse_content(encode_telemetry(counter, t_us, a, b))
    assert type(got) is Telemetry
    assert got == Telemetry(t_us, a, b, counter % COUNTER_MODULUS)


def test_content_is_a_52_byte_tm() -> None:
    """The fast path gives the SPEC's 52-byte TM content with the counter as five digits."""
    a = ChannelTelemetry(1000, 45.0, 1.5, 16380, 45.0, 1)
    b = ChannelTelemetry(-80, -2.5, 0.25, -100, 0.0, 3)
    content = encode_telemetry(100_042, 0x005C5053, a, b)
    assert len(content) == 52
    assert content.startswith(b"TM00042{\x2a") and content.endswith(b"}")


#: (field index in ChannelTelemetry, a value that does not fit that field)
BAD_FIELDS = [
    pytest.param(0, 2**40, id="position-2**40"),
    pytest.param(0, 2**31, id="position-i32-max+1"),
    pytest.param(0, -(2**31) - 1, id="position-i32-min-1"),
    pytest.param(0, 1.5, id="position-float"),
    pytest.param(1, 1e300, id="speed-past-float32"),
    pytest.param(2, -1e39, id="current-past-float32"),
    pytest.param(3, 32768, id="pwm-i16-max+1"),
    pytest.param(3, -32769, id="pwm-i16-min-1"),
    pytest.param(4, 3.5e38, id="reference-past-float32"),
    pytest.param(5, 256, id="flags-u8-max+1"),
    pytest.param(5, -1, id="flags-negative"),
]


@pytest.mark.parametrize("channel", ["a", "b"])
@pytest.mark.parametrize(("field", "value"), BAD_FIELDS)
def test_a_value_that_does_not_fit_is_refused(channel: str, field: int, value: object) -> None:
    """A field value that does not fit raises LocalProtocolError, as encode_message does: the
    caller's mistake, never a struct error or a silently wrapped value."""
    good = ChannelTelemetry(1, 2.0, 3.0, 4, 5.0, 6)
    fields: list[object] = list(good)
    fields[field] = value
    bad = ChannelTelemetry(*fields)  # type: ignore[arg-type]
    a, b = (bad, good) if channel == "a" else (good, bad)
    with pytest.raises(LocalProtocolError, match=r"^Telemetry: "):
        encode_telemetry(7, 1234, a, b)
    with pytest.raises(LocalProtocolError, match=r"^Telemetry: "):
        encode_message(Telemetry(1234, a, b), 7)


@pytest.mark.parametrize("t_us", [-1, 2**32, 2**40])
def test_a_time_that_does_not_fit_u32_is_refused(t_us: int) -> None:
    """t_us outside u32 raises LocalProtocolError on both paths (the caller masks the clock)."""
    a = ChannelTelemetry(1, 2.0, 3.0, 4, 5.0, 6)
    with pytest.raises(LocalProtocolError):
        encode_telemetry(0, t_us, a, a)
    with pytest.raises(LocalProtocolError):
        encode_message(Telemetry(t_us, a, a), 0)


@given(counters, u32, channels(f32), channels(f32), st.data())
def test_any_out_of_range_integer_field_is_refused(
    counter: int, t_us: int, a: ChannelTelemetry, b: ChannelTelemetry, data: st.DataObject
) -> None:
    """Whatever the other fields hold, one integer field out of its struct range makes both
    encoders refuse."""
    field, low, high = data.draw(st.sampled_from(
        [(0, -(2**31), 2**31 - 1), (3, -32768, 32767), (5, 0, 255)]))
    value = data.draw(st.integers(max_value=low - 1) | st.integers(min_value=high + 1))
    fields: list[object] = list(a)
    fields[field] = value
    bad = ChannelTelemetry(*fields)  # type: ignore[arg-type]
    assert outcome(lambda: encode_telemetry(counter, t_us, bad, b)) == "refused"
    assert outcome(lambda: encode_message(Telemetry(t_us, bad, b), counter)) == "refused"
