"""The sans-I/O Connection: events, statistics, heartbeat and liveness timers, parameter
requests with retries — all driven with explicit ``now`` values, no clock, no I/O."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from fpgalink import (
    Alive,
    BoardFound,
    BoardLost,
    BoardSilent,
    ChannelTelemetry,
    Connection,
    CounterDuplicate,
    CounterGap,
    Enable,
    EventsDropped,
    FrameAborted,
    LinkClosed,
    Malformed,
    NoiseDropped,
    ParamAck,
    ParameterRefused,
    ParamNack,
    ParamSet,
    RequestDone,
    RequestFailed,
    RequestTimeout,
    Role,
    Telemetry,
    encode_frame,
    lookup,
)
from fpgalink._messages import Disable

CH = ChannelTelemetry(0, 0.0, 0.0, 0, 0.0, 0)


def tm(t: int) -> Telemetry:
    return Telemetry(t, CH, CH)


def drain(conn: Connection) -> list[object]:
    return list(conn.events())


def test_telemetry_stream_with_a_gap_and_a_duplicate() -> None:
    board, host = Connection(role=Role.BOARD), Connection()
    wires = [board.send(tm(i)) for i in range(6)]
    host.receive_data(wires[0] + wires[1] + wires[3] + wires[3] + wires[4], now=0.0)
    events = drain(host)
    kinds = [type(e).__name__ for e in events]
    assert kinds == [
        "Telemetry", "BoardFound", "Telemetry", "CounterGap", "Telemetry",
        "CounterDuplicate", "Telemetry", "Telemetry",
    ] or kinds == [
        "Telemetry", "Telemetry", "CounterGap", "Telemetry", "CounterDuplicate",
        "Telemetry", "Telemetry", "BoardFound",
    ]
    assert CounterGap(1, 3) in events and CounterDuplicate(3) in events
    s = host.stats
    assert (s.telemetry_received, s.lost, s.duplicates) == (5, 1, 1)
    assert host.latest_telemetry is not None and host.latest_telemetry.t_us == 4


def test_bad_input_becomes_counted_events() -> None:
    host = Connection()
    host.receive_data(b"zz" + b"Sab" + encode_frame(b"TM00001{\x01x}") + b"SXY0000")
    events = drain(host)
    assert isinstance(events[0], NoiseDropped)
    assert isinstance(events[1], FrameAborted)
    assert isinstance(events[2], Malformed)
    assert host.stats.malformed_by_reason == {"BAD_LAYOUT": 1}
    assert host.stats.noise_bytes == 2 and host.stats.aborted_frames == 1  # "Sab" restarted
    assert host.stats.decode_errors == 2


@given(st.binary(max_size=2000))
def test_receive_never_raises(data: bytes) -> None:
    host = Connection()
    host.receive_data(data, now=1.0)
    drain(host)
    assert host.stats.bytes_received == len(data)


def test_event_queue_is_capped_and_the_drop_counted() -> None:
    board, host = Connection(role=Role.BOARD), Connection(max_events=10)
    host.receive_data(b"".join(board.send(tm(i)) for i in range(25)))
    events = drain(host)
    assert isinstance(events[-1], EventsDropped)
    assert host.stats.events_dropped == 15
    assert len(events) == 11


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


def test_heartbeat_interval_must_stay_below_the_watchdog() -> None:
    import pytest

    with pytest.raises(ValueError, match="300 ms"):
        Connection(heartbeat_interval=0.3)


def test_liveness_lost_then_found() -> None:
    board, host = Connection(role=Role.BOARD), Connection(liveness_timeout=0.7)
    host.start_liveness(0.0)
    host.receive_data(board.send(Alive()), now=0.1)
    assert isinstance(drain(host)[-1], BoardFound)
    assert host.get_timer() == 0.1 + 0.7
    host.handle_timer(0.5)
    assert drain(host) == []
    host.handle_timer(0.8)
    events = drain(host)
    assert len(events) == 1 and isinstance(events[0], BoardSilent)
    assert abs(events[0].silent_for - 0.7) < 1e-9
    assert host.stats.heartbeat_misses == 1
    host.receive_data(board.send(Alive()), now=1.0)
    assert isinstance(drain(host)[-1], BoardFound)


def board_answers(board: Connection, host_bytes: bytes, reply: object) -> bytes:
    board.receive_data(host_bytes)
    drain(board)
    return board.send(reply)  # type: ignore[arg-type]


def test_set_param_confirmed_by_echo() -> None:
    board, host = Connection(role=Role.BOARD), Connection()
    kp = lookup("Kp_Wheel_Pid")
    rid = host.set_param(kp, 1, kp.coerce(7.11), now=0.0)
    out = host.data_to_send()
    host.receive_data(board_answers(board, out, ParamAck(8, 1, 2, 7.11)), now=0.01)
    done = [e for e in drain(host) if isinstance(e, RequestDone)]
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
    board, host = Connection(role=Role.BOARD), Connection()
    period = lookup("TsTimerPeriod")
    host.set_param(period, 0, 5, now=0.0)
    host.data_to_send()
    host.receive_data(board.send(ParamAck(1, 0, 1, 10)), now=0.01)  # an older value
    assert host.stats.retries == 1
    assert host.data_to_send().startswith(b"S\\P\\S")
    host.receive_data(board.send(ParamNack(1, 0, 3)), now=0.02)
    failed = [e for e in drain(host) if isinstance(e, RequestFailed)]
    assert isinstance(failed[0].error, ParameterRefused)
    assert "value out of range" in str(failed[0].error)
    assert failed[0].error.code == 3


def test_close_and_loss_fail_pending_requests() -> None:
    host = Connection()
    host.get_param(lookup(1), 0, now=0.0)
    host.close()
    (failed,) = [e for e in drain(host) if isinstance(e, RequestFailed)]
    assert isinstance(failed.error, LinkClosed)
    host = Connection(liveness_timeout=0.2, request_timeout=1.0)
    host.start_liveness(0.0)
    host.get_param(lookup(1), 0, now=0.0)
    host.handle_timer(0.2)
    failed = next(e for e in drain(host) if isinstance(e, RequestFailed))
    assert isinstance(failed.error, BoardLost)


def test_board_role_parses_host_commands() -> None:
    host, board = Connection(), Connection(role=Role.BOARD)
    board.receive_data(host.send(Enable()) + host.send(ParamSet(1, 0, 1, 5)) + host.send(Disable()))
    events = drain(board)
    assert events[0] == Enable()
    assert events[1] == ParamSet(1, 0, 1, 5, 0)
    assert events[-1] == Disable()
