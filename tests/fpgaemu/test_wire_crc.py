"""The wire CRC end to end on an emulated board, against both firmwares: switched on by the
board's confirmation, carried by every counted message, damaged frames dropped and counted
on either side (never delivered), a lost confirmation recovered, a new host session finding
the board switched on, an older board refusing it with PN 1 (docs/protocol.md §7)."""

from __future__ import annotations

import struct

import pytest

from fpgaemu.board import Board
from fpgaemu.firmware import attach_firmware
from fpgaemu.motor import Motors
from fpgalink import Connection
from fpgalink.events import RequestDone, RequestFailed
from fpgalink.protocol import (
    FrameDecoder,
    ParamAck,
    ParamNack,
    References,
    Telemetry,
    encode_frame,
    encode_message,
    lookup,
)
from fpgalink.protocol.crc import WIRE_CRC_PARAM, CrcMismatch, append_crc, strip_crc
from tests.support.emulated import MS, Cable

#: every test but the older board's runs against the Python firmware model and the C core
both_firmwares = pytest.mark.usefixtures("each_firmware")
INT = 1


def crc_on(host: Cable) -> None:
    reply = host.set(WIRE_CRC_PARAM, 0, INT, 1)
    assert isinstance(reply, ParamAck) and reply.value == 1
    assert host.conn.wire_crc.on and host.firmware.wire_crc.on


@both_firmwares
def test_off_at_power_up_the_seeds_wire_unchanged() -> None:
    host = Cable.make()
    assert host.get(WIRE_CRC_PARAM, 0) == ParamAck(WIRE_CRC_PARAM, 0, INT, 0, 0)
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    host.run(0.01)
    host.board.run_until(host.board.now + 5 * MS)
    frames = [f for f in FrameDecoder().feed(host.board.read_host_bytes())
              if isinstance(f, bytes)]
    assert frames and all(len(f) == 52 for f in frames if f[:2] == b"TM")


@both_firmwares
def test_switched_on_every_counted_message_carries_it_and_nothing_fails() -> None:
    host = Cable.make()
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    crc_on(host)
    host.start_enabled()
    host.references(30.0, -20.0)
    host.run(0.3)
    assert host.conn.stats.crc_failures == 0 and host.firmware.stats.crc_failures == 0
    assert host.telemetry[-1].a.reference == 30.0  # the RV (with its CRC) was taken
    # on the wire: every counted frame ends in a good CRC, direct commands do not
    host.drain()
    host.board.run_until(host.board.now + 310 * MS)
    frames = [f for f in FrameDecoder().feed(host.board.read_host_bytes())
              if isinstance(f, bytes)]
    counted = [f for f in frames if f != b"E"]
    assert b"E" in frames and len(counted) >= 300
    assert all(len(f) == 54 and strip_crc(f) is not None for f in counted)


@both_firmwares
def test_a_damaged_telemetry_frame_is_counted_and_never_delivered() -> None:
    host = Cable.make()
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    crc_on(host)
    host.drain()
    host.board.run_until(host.board.now + 10 * MS)
    wire = bytearray(host.board.read_host_bytes())
    # flip one bit in the body of the fifth TM (its speed field, no framing byte involved)
    starts = [i for i in range(len(wire) - 1) if wire[i:i + 3] == b"STM"]
    at = starts[4] + 1 + 9 + 8  # START, header + "{" LEN, position: the speed's first byte
    wire[at] ^= 0x04
    assert wire[at] not in b"SP\\" and wire[at] ^ 0x04 not in b"SP\\"
    before = len(host.telemetry)
    host.conn.receive_data(bytes(wire), host.now_s)
    events = list(host.conn.events())
    delivered = [e for e in events if isinstance(e, Telemetry)]
    failed = [e for e in events if isinstance(e, CrcMismatch)]
    assert len(failed) == 1 and host.conn.stats.crc_failures == 1
    assert len(delivered) == len(starts) - 1
    counters = [tm.counter or 0 for tm in delivered]
    assert failed[0].content[2:7] == b"%05d" % (counters[3] + 1)  # the missing one
    assert len(host.telemetry) == before


@both_firmwares
def test_a_damaged_reference_is_dropped_by_the_board_and_counted() -> None:
    host = Cable.make()
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    crc_on(host)
    host.start_enabled()
    host.references(20.0, 10.0)
    host.run(0.2)
    content = bytearray(append_crc(encode_message(References(-80.0, 80.0),
                                                  host.conn.next_counter)))
    content[12] ^= 0x01  # a bit of ref_a: a different, perfectly finite wheel speed
    assert struct.unpack_from("<f", content, 9)[0] != -80.0
    host.board.host_write(encode_frame(bytes(content)))
    host.run(0.2)
    assert host.firmware.stats.crc_failures == 1
    assert host.telemetry[-1].a.reference == 20.0 and host.telemetry[-1].b.reference == 10.0
    # the same message plain (no CRC) is refused as well: once on, plain is not trusted
    plain = encode_message(References(-80.0, 80.0), host.conn.next_counter)
    host.board.host_write(encode_frame(plain))
    host.run(0.05)
    assert host.firmware.stats.crc_failures == 2
    assert host.telemetry[-1].a.reference == 20.0


def _exchange(board: Board, conn: Connection, until: int, lose: bool = False) -> None:
    """Run the board 1 ms at a time to ``until``, the host's timers served; with ``lose``
    the board's bytes of this stretch never reach the host."""
    while board.now < until:
        board.run_until(min(until, board.now + MS))
        now = board.now / 1e8
        data = board.read_host_bytes()
        if not lose:
            conn.receive_data(data, now)
        conn.handle_timer(now)
        board.host_write(conn.data_to_send())


@both_firmwares
def test_a_lost_confirmation_is_recovered_by_the_resend() -> None:
    host = Cable.make()
    board, conn = host.board, Connection(baud=None, request_timeout=0.01)
    param = lookup("WireCrc")
    request = conn.set_param(param, 0, 1, 0.0)
    board.host_write(conn.data_to_send())
    _exchange(board, conn, board.now + 5 * MS, lose=True)  # the PA (with its CRC) is lost
    assert host.firmware.wire_crc.on and not conn.wire_crc.on and conn.wire_crc.asking
    _exchange(board, conn, board.now + 50 * MS)
    events = list(conn.events())
    done = [e for e in events if isinstance(e, RequestDone)]
    assert done and done[0].request_id == request and done[0].tries == 2
    assert conn.wire_crc.on and not conn.wire_crc.asking
    assert conn.stats.crc_failures == 0


@both_firmwares
def test_a_new_host_session_finds_the_board_switched_on_and_off_again() -> None:
    host = Cable.make()
    crc_on(host)
    fresh = Connection(baud=None)
    param = lookup("WireCrc")
    fresh.get_param(param, 0, host.now_s)
    host.board.host_write(fresh.data_to_send())
    _exchange(host.board, fresh, host.board.now + 10 * MS)
    done = [e for e in fresh.events() if isinstance(e, RequestDone)]
    assert done and done[0].value == 1 and fresh.wire_crc.on
    fresh.set_param(param, 0, 0, host.board.now / 1e8)
    host.board.host_write(fresh.data_to_send())
    _exchange(host.board, fresh, host.board.now + 10 * MS)
    done = [e for e in fresh.events() if isinstance(e, RequestDone)]
    assert done and done[0].value == 0
    assert not fresh.wire_crc.on and not host.firmware.wire_crc.on
    assert fresh.stats.crc_failures == 0


def test_an_older_board_refuses_with_pn_1_and_the_host_stays_plain() -> None:
    board = Board()
    attach_firmware(board, wire_crc=False)  # a board from before the extension
    board.add_peripheral("motors", Motors())
    host = Cable(board)
    conn = host.conn
    param = lookup("WireCrc")
    conn.set_param(param, 0, 1, 0.0)
    board.host_write(conn.data_to_send())
    _exchange(board, conn, board.now + 10 * MS)
    failed = [e for e in conn.events() if isinstance(e, RequestFailed)]
    assert failed and "unknown parameter id" in str(failed[0].error)
    assert not conn.wire_crc.on and not conn.wire_crc.checking
    assert isinstance(host.set(2, 0, INT, 1), ParamAck)
    host.run(0.05)
    assert len(host.telemetry) >= 45 and conn.stats.crc_failures == 0
    assert isinstance(host.get(WIRE_CRC_PARAM, 0), ParamNack)
