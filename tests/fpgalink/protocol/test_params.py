"""SPEC §5 parameter table: lookup by name/id/suffix, and host-side validation."""

from __future__ import annotations

import math
from decimal import Decimal
from fractions import Fraction

import numpy
import pytest

from fpgalink import ParameterError, UnknownParameter
from fpgalink.protocol import PARAMETERS, ParamType, Scope, lookup, resolve
from fpgalink.protocol.params import float32, iter_addresses


def test_table_matches_spec() -> None:
    # SPEC §5's ten, then the wire CRC's switch (not in the seed; docs/protocol.md §7)
    assert [p.id for p in PARAMETERS] == list(range(1, 12))
    wire_crc = PARAMETERS[-1]
    assert (wire_crc.name, wire_crc.scope, wire_crc.type, wire_crc.default) == (
        "WireCrc", Scope.BOARD, ParamType.INT, 0)
    assert (wire_crc.minimum, wire_crc.maximum) == (0, 1)
    assert [(p.name, p.scope, p.type) for p in PARAMETERS[:3]] == [
        ("TsTimerPeriod", Scope.BOARD, ParamType.INT),
        ("GetDataPeriodical", Scope.BOARD, ParamType.INT),
        ("TorqueCoef", Scope.CHANNEL, ParamType.FLOAT),
    ]
    assert len(list(iter_addresses())) == 3 + 8 * 2


@pytest.mark.parametrize(
    ("name", "channel", "expected"),
    [
        ("Kp_Wheel_Pid", "A", (8, 1)),
        ("kp_wheel_pid", "b", (8, 2)),
        ("Kp_Wheel_PidA", None, (8, 1)),
        ("Kp_Wheel_PidB", "B", (8, 2)),
        ("TsTimerPeriod", None, (1, 0)),
        ("TsTimerPeriod", 0, (1, 0)),
        (6, 1, (6, 1)),
    ],
)
def test_resolve(name: str | int, channel: str | int | None, expected: tuple[int, int]) -> None:
    param, code = resolve(name, channel)
    assert (param.id, code) == expected


@pytest.mark.parametrize(
    ("name", "channel", "message"),
    [
        ("Kp_Whel_Pid", "A", "unknown parameter"),
        ("Kp_Wheel_Pid", None, "give channel A or B"),
        ("TsTimerPeriod", "A", "board-wide"),
        ("Kp_Wheel_PidA", "B", "name says channel A"),
        ("Kp_Wheel_Pid", "C", "unknown channel"),
        (12, None, "no parameter has id 12"),
    ],
)
def test_resolve_errors(name: str | int, channel: str | None, message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        resolve(name, channel)


def test_unknown_parameter_is_a_key_error_with_a_plain_message() -> None:
    with pytest.raises(KeyError) as info:
        lookup("nope")
    assert isinstance(info.value, UnknownParameter)
    assert str(info.value).startswith("unknown parameter 'nope'")


@pytest.mark.parametrize(
    ("name", "value", "ok"),
    [
        ("TsTimerPeriod", 1, 1), ("TsTimerPeriod", 1000, 1000), ("TsTimerPeriod", 5.0, 5),
        ("MaxControlSignal", 32760, 32760), ("IncSenzCountDirection", -1, -1),
        ("Kp_Wheel_Pid", 0, 0.0), ("Kp_Wheel_Pid", 7.11, float32(7.11)),
        ("Ti_Wheel_Pid", 1e-3, float32(1e-3)),
    ],
)
def test_coerce_accepts(name: str, value: float, ok: float) -> None:
    assert lookup(name).coerce(value) == ok


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("TsTimerPeriod", 0, "1..1000"),
        ("TsTimerPeriod", 1001, "1..1000"),
        ("TsTimerPeriod", 2.5, "integer parameter"),
        ("IncSenzCountDirection", 0, "-1 or 1"),
        ("Ti_Wheel_Pid", 0.0, "> 0"),
        ("Kp_Wheel_Pid", -0.1, "≥ 0"),
        ("Kp_Wheel_Pid", math.nan, "≥ 0"),
        ("Kp_Wheel_Pid", math.inf, "≥ 0"),
        ("Kp_Wheel_Pid", "7", "expected a number"),
        ("GetDataPeriodical", True, "expected a number"),
        ("TorqueCoef", 1e-50, "> 0"),  # rounds to 0 as float32: refused, not sent as 0
    ],
)
def test_coerce_refuses_with_the_range(name: str, value: object, message: str) -> None:
    with pytest.raises(ParameterError, match=message) as info:
        lookup(name).coerce(value)
    assert name in str(info.value)


# --- any real number, never a raw Python error -------------------------------------------------


@pytest.mark.parametrize("value", [1e39, -1e39, 3.5e38, math.inf, math.nan])
def test_values_beyond_a_float32_are_a_parameter_error_naming_the_range(value: float) -> None:
    # set_param(..., 1e39) raised a raw OverflowError from struct.
    with pytest.raises(ParameterError, match=r"≥ 0"):
        lookup("Kp_Wheel_Pid").coerce(value)
    with pytest.raises(ParameterError, match=r"1\.\.1000"):
        lookup("TsTimerPeriod").coerce(value)


def test_the_largest_float32_is_still_accepted() -> None:
    largest = 3.4028234663852886e38
    assert lookup("Kp_Wheel_Pid").coerce(largest) == largest


@pytest.mark.parametrize(
    ("value", "expected"),
    [
        (numpy.int64(7), 7),
        (numpy.float64(7.0), 7),
        (Decimal("7"), 7),
        (Fraction(14, 2), 7),
    ],
)
def test_any_real_number_type_is_accepted(value: object, expected: int) -> None:
    assert lookup("TsTimerPeriod").coerce(value) == expected
    assert type(lookup("TsTimerPeriod").coerce(value)) is int


def test_real_number_types_for_a_float_parameter() -> None:
    kp = lookup("Kp_Wheel_Pid")
    for value, expected in ((numpy.float64(7.11), 7.11), (Decimal("7.11"), 7.11),
                            (Fraction(711, 100), 7.11), (numpy.int64(7), 7.0)):
        assert kp.coerce(value) == float32(expected)
        assert type(kp.coerce(value)) is float


@pytest.mark.parametrize("value", [True, "7", None, 7j, [7], Decimal("7.5")])
def test_what_is_not_a_real_number_or_not_whole_is_refused(value: object) -> None:
    with pytest.raises(ParameterError):
        lookup("TsTimerPeriod").coerce(value)
