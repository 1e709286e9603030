"""The wire CRC's modes disagreeing (issue 37, item 7): a board whose CRC is on heard by a
host whose CRC is off, and the reverse. Its frames are recognised as the other mode's,
counted, said once, and a request left unanswered says why; never telemetry reported from a
frame the host did not check, never a silent "board not answering"."""

from __future__ import annotations

import pytest

from fpgalink import Connection, Role, WireCrcMismatchError
from fpgalink.events import Event, RequestFailed, WireCrcMismatch
from fpgalink.protocol import (
    ChannelTelemetry,
    Malformed,
    ParamAck,
    Telemetry,
    encode_frame,
    lookup,
)
from fpgalink.protocol.crc import append_crc

CH = ChannelTelemetry(0, 0.0, 0.0, 0, 0.0, 1)


def board_bytes(crc: bool, count: int = 5) -> bytes:
    board = Connection(role=Role.BOARD, baud=None, wire_crc=crc)
    for t in range(count):
        board.send(Telemetry(t, CH, CH), 0.0)
    board.send(ParamAck(1, 0, 1, 1), 0.0)
    return board.data_to_send() + b"SEP"  # E: direct, never carries the CRC


def drain(host: Connection) -> list[Event]:
    return list(host.events())


@pytest.mark.parametrize("board_crc", [True, False])
def test_frames_of_the_other_mode_are_counted_and_said_once(board_crc: bool) -> None:
    host = Connection(wire_crc=not board_crc)
    host.start(0.0)
    host.receive_data(board_bytes(board_crc), 0.0)
    host.receive_data(board_bytes(board_crc), 0.01)
    events = drain(host)
    assert [e for e in events if isinstance(e, WireCrcMismatch)] == [WireCrcMismatch(board_crc)]
    assert not [e for e in events if isinstance(e, Telemetry | ParamAck | Malformed)]
    stats = host.stats
    assert stats.crc_mode_mismatches == 12 and stats.telemetry_received == 0
    assert stats.malformed == 0 and stats.crc_failures == (0 if board_crc else 12)
    assert stats.alive_received == 2  # the board is heard all the same
    assert ("CRC-16 frames" if board_crc else "without the wire CRC") in (
        WireCrcMismatch(board_crc).describe())


@pytest.mark.parametrize("board_crc", [True, False])
def test_a_request_unanswered_meanwhile_says_why(board_crc: bool) -> None:
    host = Connection(wire_crc=not board_crc, request_tries=2)
    host.start(0.0)
    host.get_param(lookup("TsTimerPeriod"), 0, 0.0)
    host.receive_data(board_bytes(board_crc), 0.01)
    for now in (0.05, 0.1):
        host.handle_timer(now)
    (failed,) = [e for e in drain(host) if isinstance(e, RequestFailed)]
    assert isinstance(failed.error, WireCrcMismatchError)
    assert failed.error.board_crc is board_crc
    assert "no answer after 2 tries" in str(failed.error)
    assert ("the board sends CRC-16 frames and this host has the wire CRC off" if board_crc
            else "without the wire CRC and this host has it on") in str(failed.error)


def test_connected_in_the_boards_mode_the_same_frames_are_telemetry() -> None:
    for crc in (True, False):
        host = Connection(wire_crc=crc)
        host.receive_data(board_bytes(crc), 0.0)
        events = drain(host)
        assert sum(isinstance(e, Telemetry) for e in events) == 5
        assert not [e for e in events if isinstance(e, WireCrcMismatch)]
        assert host.stats.crc_mode_mismatches == 0


def test_noise_and_damage_are_not_the_other_mode() -> None:
    # A plain frame that does not parse stays Malformed for a plain host; a CRC frame with a
    # damaged CRC is a CRC failure for a CRC host, not a board in the other mode.
    plain = Connection()
    plain.receive_data(encode_frame(b"TM00001{\x01x}"), 0.0)
    assert [type(e) for e in drain(plain)] == [Malformed]
    damaged = bytearray(append_crc(b"PA00000{\x07\x01\x00\x01\x01\x00\x00\x00}"))
    damaged[-1] ^= 0x01
    crc = Connection(wire_crc=True)
    crc.receive_data(encode_frame(bytes(damaged)), 0.0)
    assert crc.stats.crc_failures == 1 and crc.stats.crc_mode_mismatches == 0
    assert not [e for e in drain(crc) if isinstance(e, WireCrcMismatch)]


def test_the_boards_answer_about_wire_crc_settles_the_mode_and_it_is_said_again() -> None:
    # Said once: then, after the board's own answer about WireCrc (the mode settled), again
    # if the board's frames disagree once more.
    host = Connection()
    host.receive_data(board_bytes(True), 0.0)
    assert len([e for e in drain(host) if isinstance(e, WireCrcMismatch)]) == 1
    host.get_param(lookup("WireCrc"), 0, 0.0)  # the handshake: either form is taken
    board = Connection(role=Role.BOARD, baud=None, wire_crc=True)
    board.send(ParamAck(11, 0, 1, 0), 0.0)
    host.receive_data(board.data_to_send(), 0.01)  # the board says 0 (in the CRC form)
    drain(host)
    assert not host.wire_crc.on
    host.receive_data(board_bytes(True), 0.02)
    assert len([e for e in drain(host) if isinstance(e, WireCrcMismatch)]) == 1
