"""The wire CRC's declaration and its two sides' rules (docs/protocol.md §7)."""

from __future__ import annotations

import struct

from hypothesis import given
from hypothesis import strategies as st

from fpgalink.protocol import (
    ChannelTelemetry,
    ParamGet,
    ParamSet,
    References,
    encode_message,
    encode_telemetry,
)
from fpgalink.protocol.crc import (
    CRC16,
    WIRE_CRC_PARAM,
    BoardWireCrc,
    CrcMismatch,
    HostWireCrc,
    append_crc,
    crc16,
    handshake_request,
    strip_crc,
)
from fpgalink.protocol.params import lookup


def test_the_declaration_is_crc16_ccitt_false() -> None:
    assert (CRC16.width, CRC16.poly, CRC16.init, CRC16.refin, CRC16.refout, CRC16.xorout) == (
        16, 0x1021, 0xFFFF, False, False, 0x0000)
    # the catalogue's check value, from the bit-by-bit definition and from the fast one
    assert CRC16.compute(b"123456789") == CRC16.check == 0x29B1
    assert crc16(b"123456789") == 0x29B1
    assert WIRE_CRC_PARAM == lookup("WireCrc").id == 11


@given(st.binary(max_size=300))
def test_the_fast_crc_is_the_definition(data: bytes) -> None:
    assert crc16(data) == CRC16.compute(data)
    table = CRC16.table()
    crc = CRC16.init
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[(crc >> 8) ^ byte]
    assert crc == crc16(data)


TM = encode_telemetry(4242, 123_456, ChannelTelemetry(-5, 44.9, 1.25, 20000, 45.0, 5),
                      ChannelTelemetry(7, -12.5, -0.5, -3000, -30.0, 1))


def test_append_and_strip_round_trip_and_little_endian() -> None:
    checked = append_crc(TM)
    assert len(checked) == len(TM) + 2
    assert struct.unpack("<H", checked[-2:])[0] == crc16(TM)
    assert strip_crc(checked) == TM
    assert strip_crc(b"") is None and strip_crc(b"\xff\xff") is None


def test_every_one_and_two_bit_error_in_a_tm_is_detected() -> None:
    checked = bytearray(append_crc(TM))
    bits = len(checked) * 8
    for i in range(bits):
        checked[i // 8] ^= 1 << (i % 8)
        assert strip_crc(bytes(checked)) is None, i
        for j in range(i + 1, bits):
            checked[j // 8] ^= 1 << (j % 8)
            assert strip_crc(bytes(checked)) is None, (i, j)
            checked[j // 8] ^= 1 << (j % 8)
        checked[i // 8] ^= 1 << (i % 8)


@given(st.binary(min_size=1, max_size=60), st.integers(1, 16))
def test_any_burst_of_up_to_16_bits_is_detected(content: bytes, burst: int) -> None:
    checked = int.from_bytes(append_crc(content), "big")
    bits = (len(content) + 2) * 8
    for start in range(0, bits - burst + 1, 7):
        pattern = (1 | (1 << (burst - 1))) << start  # first and last bit of the burst set
        damaged = (checked ^ pattern).to_bytes(len(content) + 2, "big")
        assert strip_crc(damaged) is None


def test_handshake_requests_are_ps_and_pg_naming_wire_crc() -> None:
    assert handshake_request(encode_message(ParamSet(WIRE_CRC_PARAM, 0, 1, 1), 7))
    assert handshake_request(encode_message(ParamGet(WIRE_CRC_PARAM, 0), 99999))
    assert handshake_request(encode_message(ParamSet(WIRE_CRC_PARAM, 2, 2, 1.0), 0))
    assert not handshake_request(encode_message(ParamSet(1, 0, 1, 1), 7))
    assert not handshake_request(encode_message(References(1.0, 2.0), 7))
    assert not handshake_request(append_crc(encode_message(ParamGet(WIRE_CRC_PARAM, 0), 3)))


def test_board_side_modes() -> None:
    board = BoardWireCrc()
    rv = encode_message(References(1.0, 2.0), 3)
    assert board.receive(rv) == rv and board.send(rv) == rv  # off: the seed's wire
    handshake = encode_message(ParamSet(WIRE_CRC_PARAM, 0, 1, 0), 4)
    # a CRC-carrying handshake is understood while off (a host resending a switch-off)
    assert board.receive(append_crc(handshake)) == handshake
    board.on = True
    assert board.send(rv) == append_crc(rv)
    assert board.receive(append_crc(rv)) == rv
    assert board.receive(rv) is None and board.failures == 1  # plain: fails, counted
    damaged = bytearray(append_crc(rv))
    damaged[10] ^= 0x10
    assert board.receive(bytes(damaged)) is None and board.failures == 2
    # the plain handshake is understood while on (a lost PA, a new host session)
    assert board.receive(handshake) == handshake and board.failures == 2


def test_host_side_follows_the_boards_answer() -> None:
    host = HostWireCrc()
    tm = append_crc(TM)
    assert not host.checking
    host.sent(ParamSet(WIRE_CRC_PARAM, 0, 1, 1))
    assert host.asking and not host.on
    # asking: either form is taken, nothing fails
    items, failed = host.filter([TM, tm, b"E"])
    assert items == [TM, TM, b"E"] and failed == 0
    host.answered(WIRE_CRC_PARAM, 1)
    assert host.on and not host.asking
    assert host.outgoing(TM) == tm
    items, failed = host.filter([tm, TM, b"E"])
    assert items[0] == TM and items[2] == b"E" and failed == 1
    assert isinstance(items[1], CrcMismatch) and items[1].content == TM
    # a PN leaves the mode as it was
    host.sent(ParamGet(WIRE_CRC_PARAM, 1))
    host.answered(WIRE_CRC_PARAM, None)
    assert host.on and not host.asking
    host.answered(1, 0)  # another parameter: nothing to do with the CRC
    assert host.on
    host.answered(WIRE_CRC_PARAM, 0)
    assert not host.on and not host.checking
