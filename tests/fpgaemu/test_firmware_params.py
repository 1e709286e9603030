"""Every parameter path through the whole board (SPEC §4 details, §5): PS → PA/PN, PG → PA/PN,
the PN codes in their order, the echo as the value in force, and values actually applied."""

from __future__ import annotations

import itertools
import math

import pytest

from fpgalink.protocol import NackReason, ParamAck, ParamGet, ParamNack, ParamSet, lookup
from fpgalink.protocol.params import PARAMETERS, Param, ParamType, Scope, float32
from tests.support.emulated import MS, Cable

# Every test runs against the Python firmware model and the C core (tests/support/firmwares.py).
pytestmark = pytest.mark.usefixtures("each_firmware")

INT, FLOAT = int(ParamType.INT), int(ParamType.FLOAT)
BY_ID = {p.id: p for p in PARAMETERS}
CHANNEL_PARAMS = [p for p in PARAMETERS if p.scope is Scope.CHANNEL]
BOARD_PARAMS = [p for p in PARAMETERS if p.scope is Scope.BOARD]


def valid_channel(param: Param) -> int:
    return 0 if param.scope is Scope.BOARD else 1


def a_valid_value(param: Param) -> int | float:
    """A legal value different from the default where possible."""
    return {1: 7, 2: 1, 3: 0.35, 4: 1, 5: 20000, 6: 1024, 7: -1, 8: 123.456, 9: 0.3,
            10: 0.01, 11: 1}[param.id]


@pytest.fixture
def host() -> Cable:
    return Cable.make()


def assert_nack(reply: ParamAck | ParamNack, param_id: int, channel: int, code: int) -> None:
    assert isinstance(reply, ParamNack), reply
    assert (reply.param_id, reply.channel, reply.error) == (param_id, channel, code)


def in_force(host: Cable, param: Param, channel: int) -> int | float:
    return host.firmware.values[(param.id, channel)]


# --- PN 1: unknown id -------------------------------------------------------------------------


@pytest.mark.parametrize("param_id", [0, 12, 13, 99, 255])
def test_unknown_id_is_pn1_for_set_and_get(host: Cable, param_id: int) -> None:
    assert_nack(host.set(param_id, 0, INT, 1), param_id, 0, NackReason.UNKNOWN_ID)
    assert_nack(host.set(param_id, 1, FLOAT, 1.0), param_id, 1, NackReason.UNKNOWN_ID)
    assert_nack(host.get(param_id, 0), param_id, 0, NackReason.UNKNOWN_ID)
    assert_nack(host.get(param_id, 2), param_id, 2, NackReason.UNKNOWN_ID)


# --- PN 2: bad channel ------------------------------------------------------------------------


@pytest.mark.parametrize("param", BOARD_PARAMS, ids=lambda p: p.name)
@pytest.mark.parametrize("channel", [1, 2, 3, 255])
def test_board_parameter_with_a_channel_is_pn2(host: Cable, param: Param, channel: int) -> None:
    before = in_force(host, param, 0)
    assert_nack(host.set(param.id, channel, INT, 1), param.id, channel, NackReason.BAD_CHANNEL)
    assert_nack(host.get(param.id, channel), param.id, channel, NackReason.BAD_CHANNEL)
    assert in_force(host, param, 0) == before


@pytest.mark.parametrize("param", CHANNEL_PARAMS, ids=lambda p: p.name)
@pytest.mark.parametrize("channel", [0, 3, 255])
def test_channel_parameter_with_channel_0_or_3_is_pn2(
    host: Cable, param: Param, channel: int
) -> None:
    value = a_valid_value(param)
    reply = host.set(param.id, channel, int(param.type), value)
    assert_nack(reply, param.id, channel, NackReason.BAD_CHANNEL)
    assert_nack(host.get(param.id, channel), param.id, channel, NackReason.BAD_CHANNEL)
    assert in_force(host, param, 1) == in_force(host, param, 2) == float32(param.default)


# --- PN 4: wrong type -------------------------------------------------------------------------


@pytest.mark.parametrize("param", PARAMETERS, ids=lambda p: p.name)
def test_wrong_type_code_is_pn4(host: Cable, param: Param) -> None:
    channel = valid_channel(param)
    before = in_force(host, param, channel)
    if param.type is ParamType.INT:
        # a float for an int parameter, even an integral one in range
        wrong: list[tuple[int, int | float]] = [(FLOAT, 1.0)]
    else:
        # an int for a float parameter, in range
        wrong = [(INT, 1)]
    wrong += [(7, 1), (0, 1), (3, 1), (255, 1)]
    for value_type, value in wrong:
        reply = host.set(param.id, channel, value_type, value)
        assert_nack(reply, param.id, channel, NackReason.WRONG_TYPE)
    assert in_force(host, param, channel) == before


# --- PN 3: out of range -----------------------------------------------------------------------

OUT_OF_RANGE: dict[int, list[int | float]] = {
    1: [0, -1, 1001, 2**31 - 1, -(2**31)],
    2: [-1, 2, 100],
    3: [0.0, -0.0, -1e-30, -5.0, math.nan, math.inf, -math.inf],
    4: [-1, 4, 100],
    5: [-1, 32761, 65535],
    6: [-1, 65536, 2**31 - 1],
    7: [0, 2, -2, 100],
    8: [-1e-6, -520.0, math.nan, math.inf, -math.inf],
    9: [0.0, -0.0, -0.24, math.nan, math.inf, -math.inf],
    10: [-1e-6, -1.0, math.nan, math.inf, -math.inf],
    11: [-1, 2, 100],
}
IN_RANGE_EDGES: dict[int, list[int | float]] = {
    1: [1, 1000],
    2: [0, 1],
    3: [1e-30, 1e30],
    4: [0, 1, 2, 3],  # every mode: speed and current, software and hardware
    5: [0, 32760],
    6: [0, 65535],
    7: [-1, 1],
    8: [0.0, 1e30],
    9: [1e-30, 1e30],
    10: [0.0, 1e30],
    11: [0, 1],
}


@pytest.mark.parametrize("param", PARAMETERS, ids=lambda p: p.name)
def test_out_of_range_is_pn3_and_nothing_changes(host: Cable, param: Param) -> None:
    channels = [0] if param.scope is Scope.BOARD else [1, 2]
    for channel in channels:
        before = in_force(host, param, channel)
        for value in OUT_OF_RANGE[param.id]:
            reply = host.set(param.id, channel, int(param.type), value)
            assert_nack(reply, param.id, channel, NackReason.OUT_OF_RANGE)
            assert in_force(host, param, channel) == before
        pg = host.get(param.id, channel)
        assert isinstance(pg, ParamAck) and pg.value == before


@pytest.mark.parametrize("param", PARAMETERS, ids=lambda p: p.name)
def test_range_edges_are_accepted_and_echoed(host: Cable, param: Param) -> None:
    channel = valid_channel(param)
    for value in IN_RANGE_EDGES[param.id]:
        reply = host.set(param.id, channel, int(param.type), value)
        assert isinstance(reply, ParamAck), (value, reply)
        assert reply.value == in_force(host, param, channel)
        expected = value if param.type is ParamType.INT else float32(value)
        assert reply.value == expected


# --- check order: the first failure answers ---------------------------------------------------


@pytest.mark.parametrize(
    ("body", "code"),
    [
        # unknown id beats bad channel, wrong type and out of range
        ((12, 7, 7, 12345), NackReason.UNKNOWN_ID),
        ((0, 3, 2, math.nan), NackReason.UNKNOWN_ID),
        # bad channel beats wrong type and out of range
        ((1, 1, 2, math.nan), NackReason.BAD_CHANNEL),
        ((8, 0, 1, -5), NackReason.BAD_CHANNEL),
        ((8, 3, 7, 0), NackReason.BAD_CHANNEL),
        ((4, 0, 1, 3), NackReason.BAD_CHANNEL),
        # wrong type beats out of range
        ((1, 0, 2, 5000.0), NackReason.WRONG_TYPE),
        ((8, 1, 1, -5), NackReason.WRONG_TYPE),
        ((9, 2, 7, 0), NackReason.WRONG_TYPE),
        ((4, 1, 2, 3.0), NackReason.WRONG_TYPE),
        ((3, 1, 1, 0), NackReason.WRONG_TYPE),
        # only out of range left
        ((4, 2, 1, 4), NackReason.OUT_OF_RANGE),
    ],
)
def test_check_order_first_failure_answers(
    host: Cable, body: tuple[int, int, int, int | float], code: int
) -> None:
    param_id, channel, value_type, value = body
    assert_nack(host.request(ParamSet(param_id, channel, value_type, value)),
                param_id, channel, code)


# --- PG and PA --------------------------------------------------------------------------------


def test_pg_of_every_parameter_answers_the_power_up_value(host: Cable) -> None:
    for param in PARAMETERS:
        channels = [0] if param.scope is Scope.BOARD else [1, 2]
        for channel in channels:
            reply = host.get(param.id, channel)
            assert isinstance(reply, ParamAck)
            assert (reply.param_id, reply.channel, reply.value_type) == (
                param.id, channel, int(param.type))
            default = param.default
            assert reply.value == (default if param.type is ParamType.INT else float32(default))
            assert reply.value == in_force(host, param, channel)


@pytest.mark.parametrize("param", PARAMETERS, ids=lambda p: p.name)
def test_ps_echo_is_the_value_in_force_and_pg_agrees(host: Cable, param: Param) -> None:
    channel = valid_channel(param)
    value = a_valid_value(param)
    reply = host.set(param.id, channel, int(param.type), value)
    assert isinstance(reply, ParamAck)
    assert (reply.param_id, reply.channel, reply.value_type) == (
        param.id, channel, int(param.type))
    stored = in_force(host, param, channel)
    assert reply.value == stored
    if param.type is ParamType.FLOAT:
        # the board keeps float32: none of these is exact, the echo says so
        assert stored == float32(float(value)) and stored != value
    else:
        assert stored == value
    got = host.get(param.id, channel)
    assert isinstance(got, ParamAck) and got.value == stored
    if param.scope is Scope.CHANNEL:
        # the other channel is untouched
        other = host.get(param.id, 2)
        assert isinstance(other, ParamAck)
        assert other.value == float32(param.default)


def test_gains_reach_the_pid(host: Cable) -> None:
    for param_id, value in ((8, 300.5), (9, 0.3), (10, 0.02)):
        assert isinstance(host.set(param_id, 2, FLOAT, value), ParamAck)
    gains = host.firmware.channels[2].pid.gains
    assert (gains.kp, gains.ti, gains.td) == (float32(300.5), float32(0.3), float32(0.02))
    assert host.firmware.channels[1].pid.gains.kp == lookup("Kp_Wheel_Pid").default


def test_every_request_gets_exactly_one_reply_with_the_next_counter(host: Cable) -> None:
    requests: list[ParamSet | ParamGet] = [
        ParamSet(1, 0, INT, 2), ParamGet(99, 0), ParamSet(8, 0, FLOAT, 1.0),
        ParamGet(5, 1), ParamSet(7, 1, INT, 0),
    ]
    replies = [host.request(r) for r in requests]
    assert [type(r) for r in replies] == [ParamAck, ParamNack, ParamNack, ParamAck, ParamNack]
    assert [r.counter for r in replies] == list(range(5))
    assert host.firmware.stats.refusals == 3


# --- values actually applied ------------------------------------------------------------------


def test_timer_period_5_ms_spaces_tm_5_ms_apart(host: Cable) -> None:
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    host.run(0.02)
    spacing_1 = {b.t_us - a.t_us for a, b in zip(host.telemetry, host.telemetry[1:], strict=False)}
    assert spacing_1 == {1000}
    assert isinstance(host.set(1, 0, INT, 5), ParamAck)
    mark = len(host.telemetry)
    host.run(0.1)
    later = host.telemetry[mark + 2:]
    spacing_5 = {b.t_us - a.t_us for a, b in itertools.pairwise(later)}
    assert spacing_5 == {5000}
    assert host.timer.period_cycles == 5 * MS


def test_max_control_signal_clamps_the_tm_pwm(host: Cable) -> None:
    assert isinstance(host.set(5, 1, INT, 5000), ParamAck)
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    host.start_enabled()
    host.run(0.01)
    host.references(80.0, 80.0)
    host.run(1.0)
    driven = host.telemetry[-900:]
    assert max(abs(tm.a.pwm) for tm in driven) == 5000
    assert all(tm.a.saturated for tm in driven[100:])
    # channel B keeps the full range
    assert max(tm.b.pwm for tm in driven) == 32760
    # and the wheel settles where the clamp leaves it: 5000/32760 of full speed
    assert driven[-1].a.speed == pytest.approx(90.0 * 5000 / 32760, rel=0.02)


def test_count_direction_minus_1_flips_position_and_speed(host: Cable) -> None:
    # Both wheels driven identically: a low clamp keeps each at its limit (channel A's loop
    # sees the opposite sign and runs to the clamp too), so the physics is the same.
    for channel in (1, 2):
        assert isinstance(host.set(5, channel, INT, 3276), ParamAck)
    assert isinstance(host.set(7, 1, INT, -1), ParamAck)
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    host.start_enabled()
    host.references(20.0, 20.0)
    host.run(1.0)
    last = host.telemetry[-1]
    assert last.a.pwm == last.b.pwm == 3276
    assert last.b.position > 50 and last.b.speed > 8.0
    assert last.a.position == -last.b.position
    assert last.a.speed == pytest.approx(-last.b.speed, rel=1e-6)


def test_get_data_periodical_0_stops_tm(host: Cable) -> None:
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    host.run(0.05)
    assert len(host.telemetry) >= 49
    assert isinstance(host.set(2, 0, INT, 0), ParamAck)
    host.run(0.002)
    count = len(host.telemetry)
    host.run(0.5)
    assert len(host.telemetry) == count
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    host.run(0.05)
    assert len(host.telemetry) >= count + 49
