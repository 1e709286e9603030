"""The sans-I/O Connection: events and their order, statistics, heartbeat and liveness timers,
the request table, reference pacing, port loss and replug — all driven with explicit ``now``
values, no clock, no I/O."""

from __future__ import annotations

import math
import tracemalloc

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgalink import (
    BoardLost,
    Connection,
    LinkClosed,
    LocalProtocolError,
    ParameterRefused,
    RequestTimeout,
    Role,
    Telemetry,
    ValueMismatch,
)
from fpgalink.connection import REQUEST_TABLE, Answer, Liveness, Outcome
from fpgalink.events import (
    BoardBack,
    BoardFound,
    BoardRestarted,
    BoardResynced,
    BoardSilent,
    CounterDuplicate,
    CounterGap,
    EventsDropped,
    PortRestored,
    RequestAskedAgain,
    RequestDone,
    RequestFailed,
    SetWithdrawn,
    WithdrawnSetLanded,
)
from fpgalink.protocol import (
    FLOAT32_MAX,
    Alive,
    ChannelTelemetry,
    Disable,
    Enable,
    Event,
    FrameAborted,
    Malformed,
    Message,
    NoiseDropped,
    ParamAck,
    ParamNack,
    ParamSet,
    References,
    encode_frame,
    float32,
    lookup,
)
from tests.support.wire import sent

CH = ChannelTelemetry(0, 0.0, 0.0, 0, 0.0, 0)


def tm(t: int) -> Telemetry:
    return Telemetry(t, CH, CH)


def drain(conn: Connection) -> list[Event]:
    return list(conn.events())


def board_bytes(*messages: Message | Alive) -> bytes:
    board = Connection(role=Role.BOARD, baud=None)
    for message in messages:
        board.send(message, 0.0)
    return board.data_to_send()


# --- events and their order -------------------------------------------------------------------


def test_telemetry_stream_with_a_gap_and_a_duplicate_in_a_defined_order() -> None:
    board, host = Connection(role=Role.BOARD), Connection()
    wires = [sent(tm(i), board) for i in range(6)]
    host.receive_data(wires[0] + wires[1] + wires[3] + wires[3] + wires[4], now=0.0)
    events = drain(host)
    # The board is found before the message that revealed it is delivered.
    assert [type(e).__name__ for e in events] == [
        "BoardFound", "Telemetry", "Telemetry", "CounterGap", "Telemetry",
        "CounterDuplicate", "Telemetry", "Telemetry",
    ]
    assert CounterGap(1, 3) in events and CounterDuplicate(3) in events
    s = host.stats
    assert (s.telemetry_received, s.lost, s.duplicates) == (5, 1, 1)
    assert host.latest_telemetry is not None and host.latest_telemetry.t_us == 4


def test_board_found_precedes_whatever_message_reveals_the_board() -> None:
    for first in (Alive(), ParamAck(1, 0, 1, 1), tm(0)):
        host = Connection()
        host.receive_data(b"noise" + board_bytes(first), now=0.0)
        kinds = [type(e) for e in drain(host)]
        assert kinds == [NoiseDropped, BoardFound, type(first)]


def test_bad_input_becomes_counted_events_and_does_not_reveal_a_board() -> None:
    host = Connection()
    host.receive_data(b"zz" + b"Sab" + encode_frame(b"TM00001{\x01x}") + b"SXY0000", now=0.0)
    events = drain(host)
    assert [type(e) for e in events] == [NoiseDropped, FrameAborted, Malformed]
    assert host.stats.malformed_by_reason == {"BAD_LAYOUT": 1}
    assert host.stats.noise_bytes == 2 and host.stats.aborted_frames == 1  # "Sab" restarted
    assert host.stats.decode_errors == 2
    assert host.liveness is Liveness.UNKNOWN


@given(st.binary(max_size=2000))
def test_receive_never_raises(data: bytes) -> None:
    host = Connection()
    host.receive_data(data, now=1.0)
    drain(host)
    assert host.stats.bytes_received == len(data)


def test_every_event_is_an_event() -> None:
    host = Connection(liveness_timeout=0.1)
    host.start(0.0)
    host.receive_data(b"x" + board_bytes(tm(0), tm(5), Alive()) + b"SabS", now=0.0)
    host.handle_timer(1.0)
    events = drain(host)
    assert len(events) >= 6 and all(isinstance(e, Event) for e in events)


def test_receive_data_needs_now() -> None:
    with pytest.raises(TypeError):
        Connection().receive_data(b"SEP")  # type: ignore[call-arg]


# --- the event cap ----------------------------------------------------------------------------


def test_event_queue_is_capped_and_the_drop_counted() -> None:
    host = Connection(max_events=10)
    host.receive_data(board_bytes(*(tm(i) for i in range(25))), now=0.0)
    events = drain(host)
    assert isinstance(events[-1], EventsDropped)
    # BoardFound settles liveness: it is kept while 16 telemetry samples are dropped.
    assert isinstance(events[0], BoardFound)
    assert host.stats.events_dropped == 16 and events[-1] == EventsDropped(16)
    assert len(events) == 11


@pytest.mark.parametrize(("attack", "size"), [(b"S", 10_000_000), (b"SP", 1_000_000),
                                             (b"Sab", 2_000_000)],
                         ids=["starts", "empty frames", "restarts"])
def test_the_cap_holds_while_decoding_one_huge_read(attack: bytes, size: int) -> None:
    # Megabytes in one call, every few bytes an event (a restart, an empty frame and its
    # malformed message). The cap must hold while decoding, not only after the call: 10 MB
    # of START bytes took +597 MB before.
    host = Connection(max_events=1000)
    data = attack * (size // len(attack))
    tracemalloc.start()
    try:
        host.receive_data(data, now=0.0)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert host.pending_events <= 1001
    assert peak < 20_000_000, f"peak {peak / 1e6:.0f} MB while decoding"
    s = host.stats
    assert s.bytes_received == len(data)
    # Every frame the stream opened is accounted for: delivered (malformed) or aborted, but
    # the last, still pending.
    frames = len(data) // len(attack)
    assert s.malformed + s.aborted_frames == frames - (attack != b"SP")


def test_request_outcomes_survive_an_overflowing_queue() -> None:
    host = Connection(max_events=5)
    rid = host.get_param(lookup(1), 0, now=0.0)
    host.data_to_send()
    host.receive_data(board_bytes(ParamAck(1, 0, 1, 7), *(tm(i) for i in range(40))), now=0.0)
    events = drain(host)
    assert RequestDone(rid, lookup(1), 0, 7, 1) in events


# --- heartbeat and liveness -------------------------------------------------------------------


def test_heartbeat_every_interval_and_rd_on_disable() -> None:
    host = Connection(heartbeat_interval=0.1)
    host.enable(now=0.0)
    assert host.data_to_send() == b"SREP"
    assert host.get_timer() == 0.1
    host.handle_timer(0.05)
    assert host.data_to_send() == b""
    host.handle_timer(0.1)
    assert host.data_to_send() == b"SREP"
    host.disable(now=0.15)
    assert host.data_to_send() == b"SRDP"
    assert host.get_timer() is None
    assert host.stats.heartbeats_sent == 2


@pytest.mark.parametrize("interval", [0.3, 0.0, -1.0])
def test_heartbeat_interval_must_stay_below_the_watchdog(interval: float) -> None:
    with pytest.raises(ValueError, match="300 ms"):
        Connection(heartbeat_interval=interval)


@pytest.mark.parametrize("name", ["request_timeout", "liveness_timeout", "max_reference_delay"])
@pytest.mark.parametrize("value", [0.0, -1.0, math.inf, math.nan])
def test_timeouts_must_be_positive_and_finite(name: str, value: float) -> None:
    with pytest.raises(ValueError, match=name):
        Connection(**{name: value})  # type: ignore[arg-type]


def test_liveness_lost_then_found() -> None:
    host = Connection(liveness_timeout=0.7)
    host.start(0.0)
    host.receive_data(board_bytes(Alive()), now=0.1)
    assert drain(host) == [BoardFound(), Alive()]
    assert host.get_timer() == pytest.approx(0.1 + 0.7)
    host.handle_timer(0.5)
    assert drain(host) == []
    host.handle_timer(0.8)
    events = drain(host)
    assert len(events) == 1 and isinstance(events[0], BoardSilent)
    assert events[0].silent_for == pytest.approx(0.7)
    assert host.stats.heartbeat_misses == 1
    # Heard again after a silence: it may have restarted meanwhile. It is asked (a PG), and
    # the counter of what it says next decides.
    host.receive_data(board_bytes(Alive()), now=1.0)
    assert drain(host) == [BoardFound(), Alive()]
    assert host.verifying and b"PG" in host.data_to_send()
    host.receive_data(board_bytes(ParamAck(2, 0, 1, 0)), now=1.01)  # counter 00000: first
    assert BoardBack("heard again after 0.900 s of silence") in drain(host)
    assert not host.verifying


# --- the request table ------------------------------------------------------------------------


def test_the_request_table_covers_every_answer_with_and_without_tries_left() -> None:
    assert set(REQUEST_TABLE) == {(a, left) for a in Answer for left in (True, False)}
    assert REQUEST_TABLE[(Answer.OTHER_VALUE, True)] is Outcome.RESEND
    assert REQUEST_TABLE[(Answer.OTHER_VALUE, False)] is Outcome.FAIL_MISMATCH
    assert REQUEST_TABLE[(Answer.NO_ANSWER, False)] is Outcome.FAIL_TIMEOUT


def answer(host: Connection, reply: Message, now: float = 0.01) -> list[Event]:
    host.receive_data(board_bytes(reply), now=now)
    return drain(host)


def test_set_param_confirmed_by_echo() -> None:
    host = Connection()
    kp = lookup("Kp_Wheel_Pid")
    rid = host.set_param(kp, 1, kp.coerce(7.11), now=0.0)
    host.data_to_send()
    done = [e for e in answer(host, ParamAck(8, 1, 2, 7.11)) if isinstance(e, RequestDone)]
    assert done == [RequestDone(rid, kp, 1, kp.coerce(7.11), 1)]
    assert host.pending_requests == 0


def test_set_param_resends_on_timeout_then_gives_up() -> None:
    host = Connection(request_timeout=0.05, request_tries=3)
    ts = lookup("TsTimerPeriod")
    host.set_param(ts, 0, 5, now=0.0)
    first = host.data_to_send()
    host.handle_timer(host.get_timer() or 0)
    second = host.data_to_send()
    assert first != second  # each resend takes the next counter value
    assert first[:3] == second[:3] == b"S\\P"
    host.handle_timer(host.get_timer() or 0)
    host.handle_timer(host.get_timer() or 0)
    assert host.get_timer() is None
    failed = [e for e in drain(host) if isinstance(e, RequestFailed)]
    assert len(failed) == 1
    assert isinstance(failed[0].error, RequestTimeout)
    assert "3 tries" in str(failed[0].error)
    assert host.stats.retries == 2


def test_mismatched_echo_resends_and_nack_is_final() -> None:
    host = Connection()
    host.set_param(lookup("TsTimerPeriod"), 0, 5, now=0.0)
    host.data_to_send()
    answer(host, ParamAck(1, 0, 1, 10))  # an older value
    assert host.stats.retries == 1 and host.stats.echo_mismatches == 1
    assert host.data_to_send().startswith(b"S\\P\\S")
    failed = [e for e in answer(host, ParamNack(1, 0, 3)) if isinstance(e, RequestFailed)]
    assert isinstance(failed[0].error, ParameterRefused)
    assert "value out of range" in str(failed[0].error)
    assert failed[0].error.code == 3


# --- hostile echoes: never an exception, never a wrong value confirmed -------------------------


def fail_after_echoes(name: str, value: int | float, echo: ParamAck, tries: int = 3
                      ) -> list[Event]:
    param = lookup(name)
    host = Connection(request_tries=tries)
    host.set_param(param, 0, param.coerce(value), now=0.0)
    events: list[Event] = []
    for k in range(tries):
        host.data_to_send()
        events += answer(host, echo, now=0.001 * (k + 1))
    return events


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 5.7, 5.0])
def test_a_float_echo_for_an_integer_parameter_is_another_value(bad: float) -> None:
    events = fail_after_echoes("TsTimerPeriod", 5, ParamAck(1, 0, 2, bad))
    assert not [e for e in events if isinstance(e, RequestDone)]
    (failed,) = [e for e in events if isinstance(e, RequestFailed)]
    assert isinstance(failed.error, ValueMismatch)
    assert "answered with another value" in str(failed.error)
    assert failed.tries == 3


def test_a_close_float_is_not_the_value_sent() -> None:
    events = fail_after_echoes("GetDataPeriodical", 0, ParamAck(2, 0, 2, 0.7))
    (failed,) = [e for e in events if isinstance(e, RequestFailed)]
    assert isinstance(failed.error, ValueMismatch) and failed.error.answered == pytest.approx(0.7)


@pytest.mark.parametrize("type_code", [3, 9, 0, 255])
def test_an_unknown_type_code_with_the_same_raw_value_is_not_a_confirmation(type_code: int
                                                                            ) -> None:
    events = fail_after_echoes("TsTimerPeriod", 5, ParamAck(1, 0, type_code, 5))
    (failed,) = [e for e in events if isinstance(e, RequestFailed)]
    assert isinstance(failed.error, ValueMismatch)


def test_a_float_echo_must_be_float32_exact() -> None:
    kp = lookup("Kp_Wheel_Pid")
    host = Connection()
    host.set_param(kp, 1, kp.coerce(7.11), now=0.0)
    host.data_to_send()
    # 7.1100001 rounds to another float32 than 7.11: not what was sent.
    assert not [e for e in answer(host, ParamAck(8, 1, 2, 7.1100006)) if
                isinstance(e, RequestDone)]
    done = [e for e in answer(host, ParamAck(8, 1, 2, 7.11)) if isinstance(e, RequestDone)]
    assert len(done) == 1


def test_a_timeout_after_a_wrong_echo_says_another_value_not_no_answer() -> None:
    host = Connection(request_tries=2, request_timeout=0.05)
    host.set_param(lookup("TsTimerPeriod"), 0, 5, now=0.0)
    host.data_to_send()
    answer(host, ParamAck(1, 0, 1, 6), now=0.01)  # try 2 goes out at once
    host.handle_timer(0.2)
    (failed,) = [e for e in drain(host) if isinstance(e, RequestFailed)]
    assert isinstance(failed.error, ValueMismatch) and failed.error.answered == 6


def test_a_get_takes_any_value_of_the_right_type() -> None:
    host = Connection()
    rid = host.get_param(lookup("Kp_Wheel_Pid"), 2, now=0.0)
    host.data_to_send()
    events = answer(host, ParamAck(8, 2, 1, 3))  # an integer for a float parameter
    assert not [e for e in events if isinstance(e, RequestDone)]
    events = answer(host, ParamAck(8, 2, 2, math.nan))
    (done,) = [e for e in events if isinstance(e, RequestDone)]
    assert done.request_id == rid and math.isnan(done.value)


# --- references -------------------------------------------------------------------------------


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e39, -3.5e38])
def test_references_outside_float32_are_refused_before_anything_is_sent(bad: float) -> None:
    host = Connection()
    with pytest.raises(LocalProtocolError, match="finite"):
        host.send(References(bad, 0.0), 0.0)
    with pytest.raises(LocalProtocolError, match="finite"):
        host.send(References(0.0, bad), 0.0)
    assert host.data_to_send() == b"" and host.next_counter == 0


def test_a_held_reference_out_of_range_fails_at_send_not_later() -> None:
    # The line is backed up, so a reference would be held and encoded later: the range check
    # must still happen when the caller sends it.
    host = Connection(baud=1_000_000, max_reference_delay=1e-6)
    host.send(References(1.0, 0.0), 0.0)
    host.send(References(2.0, 0.0), 0.0)  # held: the first still occupies the line
    with pytest.raises(LocalProtocolError, match="float32"):
        host.send(References(1e39, 0.0), 0.0)
    assert float32(FLOAT32_MAX) == FLOAT32_MAX


def test_references_never_queue_behind_more_than_the_allowed_delay() -> None:
    # 10,000 references in one instant at 1 MBd (21 wire bytes each: 210 ms of line time).
    host = Connection(baud=1_000_000, max_reference_delay=0.005)
    wire = b""
    for k in range(10_000):
        host.send(References(float(k), 0.0), 0.0)
        wire += host.data_to_send()
    # What went out at once fits the allowed delay; one waits, the rest were superseded.
    assert len(wire) * 10e-6 <= 0.005 + 21 * 10e-6
    sent_now = wire.count(b"RV")
    assert host.stats.references_superseded == 10_000 - sent_now - 1
    # When the line has room, the newest reference goes, and only it.
    timer = host.get_timer()
    assert timer is not None and timer <= 0.001
    host.handle_timer(timer)
    last = host.data_to_send()
    events = [e for e in _board_view(last) if isinstance(e, References)]
    assert events == [References(9999.0, 0.0, sent_now)]


def _board_view(wire: bytes) -> list[Event]:
    board = Connection(role=Role.BOARD, baud=None)
    board.receive_data(wire, 0.0)
    return drain(board)


def test_references_at_1_khz_go_out_at_once() -> None:
    host = Connection(baud=1_000_000)
    for k in range(1000):
        host.send(References(1.0, 2.0), k * 0.001)
        assert host.data_to_send().count(b"RV") == 1
    assert host.stats.references_superseded == 0


# --- port loss, replug, close -----------------------------------------------------------------


def test_close_and_loss_fail_pending_requests() -> None:
    host = Connection()
    host.get_param(lookup(1), 0, now=0.0)
    host.close(0.0)
    (failed,) = [e for e in drain(host) if isinstance(e, RequestFailed)]
    assert isinstance(failed.error, LinkClosed)
    host = Connection(liveness_timeout=0.2, request_timeout=1.0)
    host.start(0.0)
    host.get_param(lookup(1), 0, now=0.0)
    host.handle_timer(0.2)
    failed = next(e for e in drain(host) if isinstance(e, RequestFailed))
    assert isinstance(failed.error, BoardLost)


def test_close_of_an_enabled_link_sends_rd_last() -> None:
    host = Connection()
    host.enable(0.0)
    host.data_to_send()
    host.close(0.01)
    assert host.data_to_send() == b"SRDP"
    assert host.get_timer() is None


def test_port_lost_then_reconnected_owns_what_a_replug_resets() -> None:
    host = Connection(liveness_timeout=0.5)
    host.start(0.0)
    host.enable(0.0)
    host.receive_data(board_bytes(tm(0), tm(1)) + b"STM000", now=0.01)  # half a frame pending
    host.get_param(lookup(1), 0, now=0.02)
    host.data_to_send()
    drain(host)
    host.port_lost(0.05, "unplugged")
    (failed,) = [e for e in drain(host) if isinstance(e, RequestFailed)]
    assert isinstance(failed.error, BoardLost) and "unplugged" in str(failed.error)
    assert host.liveness is Liveness.LOST and host.stats.port_losses == 1
    host.handle_timer(0.3)  # no heartbeat onto a port that is gone
    assert host.data_to_send() == b""
    assert not host.enabled  # nothing could keep the board enabled: its watchdog lapsed
    host.reconnected(1.0)
    # Nothing enables the board again by itself. It may have restarted: its counter starts
    # over without a gap, and the half frame from before is gone.
    assert host.data_to_send() == b""
    liveness: Liveness = host.liveness
    assert host.stats.reconnects == 1 and liveness is Liveness.UNKNOWN
    host.receive_data(board_bytes(tm(0)), now=1.01)
    assert [type(e) for e in drain(host)] == [PortRestored, BoardFound, BoardRestarted,
                                              BoardResynced, Telemetry]
    assert host.stats.lost == 0 and host.stats.duplicates == 0 and host.stats.restarts == 1
    # Silence on the new port is judged from the replug on: lost 0.5 s after the last
    # message, not at once for the time the port was gone.
    host.disable(1.02)
    host.handle_timer(1.5)
    assert not [e for e in drain(host) if isinstance(e, BoardSilent)]
    host.handle_timer(1.52)
    assert [type(e) for e in drain(host)] == [BoardSilent]


def test_board_role_parses_host_commands() -> None:
    host, board = Connection(), Connection(role=Role.BOARD)
    for message in (Enable(), ParamSet(1, 0, 1, 5), Disable()):
        host.send(message, 0.0)
    board.receive_data(host.data_to_send(), now=0.0)
    events = drain(board)
    assert events[0] == BoardFound()
    assert events[1] == Enable()
    assert events[2] == ParamSet(1, 0, 1, 5, 0)
    assert events[-1] == Disable()


@pytest.mark.parametrize("role", list(Role))
def test_a_side_refuses_to_send_the_other_sides_messages(role: Role) -> None:
    other = ParamAck(1, 0, 1, 1) if role is Role.HOST else ParamSet(1, 0, 1, 1)
    with pytest.raises(LocalProtocolError, match="does not send"):
        Connection(role=role).send(other, 0.0)


# --- a withdrawn request (issue 37, item 8) ----------------------------------------------------


def test_a_withdrawn_set_is_read_back_and_a_newer_set_decides() -> None:
    host, board = Connection(), Connection(role=Role.BOARD, baud=None)

    def reply(message: Message, now: float) -> list[Event]:
        host.receive_data(sent(message, board), now)
        return drain(host)

    kp = lookup("Kp_Wheel_Pid")
    host.set_param(kp, 1, 300.0, now=0.0)
    host.data_to_send()
    reply(ParamAck(8, 1, 2, 300.0), 0.001)
    withdrawn = host.set_param(kp, 1, 400.0, now=0.01)
    host.data_to_send()
    host.cancel_request(withdrawn, now=0.02)
    assert drain(host) == [SetWithdrawn(withdrawn, kp, 1, 400.0)]
    asked = host.data_to_send()
    assert b"PG" in asked and b"PS" not in asked  # read back, never sent again
    host.handle_timer(0.065)  # when its second try would have gone: none does, ever
    assert b"PS" not in host.data_to_send()
    # A newer set decides what the board holds: the read-back showing the withdrawn value
    # sets nothing back.
    host.set_param(kp, 1, 500.0, now=0.07)
    host.data_to_send()
    events = reply(ParamAck(8, 1, 2, 400.0), 0.08) + reply(ParamAck(8, 1, 2, 500.0), 0.09)
    assert not [e for e in events if isinstance(e, WithdrawnSetLanded)]
    assert host.held[(8, 1)][2] == 500.0 and host.pending_requests == 0
    host.cancel_request(10_000, now=0.1)  # no such request: nothing happens
    assert host.data_to_send() == b"" and drain(host) == []


def test_each_round_of_a_request_is_judged_by_its_own_answers() -> None:
    # Another value answered in a first round (a late answer to an older question, say),
    # then nothing: the last round ends unanswered, "no answer" (RequestTimeout: the caller
    # asks again), not "another value" from a round before, as when each round was a request
    # of its own. (A robot quieting a board found streaming failed to start on the late 1.)
    host = Connection(request_tries=2, unanswered_rounds=1)
    host.start(0.0)
    host.set_param(lookup("GetDataPeriodical"), 0, 0, now=0.0)
    host.data_to_send()
    answer(host, ParamAck(2, 0, 1, 1), now=0.01)  # another value: resent
    events: list[Event] = []
    while not any(isinstance(e, RequestFailed) for e in events):  # a new round, unanswered
        now = host.get_timer() or 0.0
        assert now < 1.0
        host.receive_data(board_bytes(Alive()), now)  # the board heard all along
        host.handle_timer(now)
        events += drain(host)
    assert sum(isinstance(e, RequestAskedAgain) for e in events) == 1
    (failed,) = [e for e in events if isinstance(e, RequestFailed)]
    assert isinstance(failed.error, RequestTimeout), failed.error
