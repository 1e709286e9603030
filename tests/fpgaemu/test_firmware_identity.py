"""Board identity on an emulated board, against both firmwares (the Python model and the C
core in co-simulation): ``IQ`` answered with ``IA`` carrying the nonce, the declaration hash
this library computes, the firmware's version and build and the board's serial — the same
answer from both, to the byte; with the wire CRC on too; a seed board (no ``IQ``) counts it
as unknown and answers nothing."""

from __future__ import annotations

import pytest

from fpgaemu.board import Board
from fpgaemu.build import build_board
from fpgaemu.firmware import FIRMWARE_BUILD, FIRMWARE_VERSION, attach_firmware, emulated_serial
from fpgaemu.motor import Motors
from fpgaemu.timeline import ms
from fpgalink.protocol import (
    FrameDecoder,
    ParamAck,
    ParamSet,
    encode_frame,
    encode_message,
    parse_content,
)
from fpgalink.protocol.catalogue import IdentityAnswer, IdentityQuery, Parsed
from fpgalink.protocol.crc import WIRE_CRC_PARAM, append_crc, strip_crc
from fpgalink.protocol.identity import declarations_hash


def ask(board: Board, content: bytes, *, crc: bool = False) -> list[Parsed]:
    """Put one frame on the board's RX pin, run 5 ms, and return what it answered (``TM``
    and ``E`` left out), with the CRC checked and stripped when it is on."""
    board.host_write(encode_frame(append_crc(content) if crc else content))
    board.run_until(board.now + ms(5))
    out = []
    for frame in FrameDecoder().feed(board.read_host_bytes()):
        if type(frame) is not bytes or frame == b"E":
            continue
        if crc:
            stripped = strip_crc(frame)
            assert isinstance(stripped, bytes), frame
            frame = stripped
        out.append(parse_content(frame))
    return out


def test_the_board_answers_iq_with_its_identity(firmware_kind: str) -> None:
    board = build_board(seed=7, firmware=firmware_kind)
    answers = ask(board, encode_message(IdentityQuery(0xFEED_F00D), 3))
    assert answers == [IdentityAnswer(0xFEED_F00D, declarations_hash(), *FIRMWARE_VERSION,
                                      FIRMWARE_BUILD, emulated_serial(7), counter=0)]
    # the next one takes the next counter and echoes its own nonce
    assert ask(board, encode_message(IdentityQuery(0), 4)) == [
        IdentityAnswer(0, declarations_hash(), *FIRMWARE_VERSION, FIRMWARE_BUILD,
                       emulated_serial(7), counter=1)]


def test_both_firmwares_answer_alike_to_the_byte() -> None:
    """The Python model and the C core (co-simulation) give the same IA bytes: the C's hash
    is the generated header's, the Python's this library's."""
    from tests.support.firmwares import require_c_firmware

    require_c_firmware()
    wires = []
    for kind in ("python", "c"):
        board = build_board(seed=2, firmware=kind)
        board.host_write(encode_frame(encode_message(IdentityQuery(12345), 0)))
        board.run_until(ms(5))
        wires.append(board.read_host_bytes())
    assert wires[0] == wires[1] and b"IA00000" in wires[0]


def test_identity_travels_with_the_wire_crc_on(firmware_kind: str) -> None:
    board = build_board(firmware=firmware_kind)
    (echo,) = ask(board, encode_message(ParamSet(WIRE_CRC_PARAM, 0, 1, 1), 0), crc=True)
    assert isinstance(echo, ParamAck) and echo.value == 1
    (answer,) = ask(board, encode_message(IdentityQuery(99), 1), crc=True)
    assert isinstance(answer, IdentityAnswer) and answer.nonce == 99
    assert answer.declarations == declarations_hash()


@pytest.mark.parametrize("damaged", [b"IQ00000{\x03\x01\x02\x03}", b"IQ00000{\x04\x01\x02\x03"])
def test_a_malformed_iq_is_counted_and_unanswered(firmware_kind: str, damaged: bytes) -> None:
    board = build_board(firmware=firmware_kind)
    assert ask(board, damaged) == []
    assert board.peripherals["firmware"].stats.malformed == 1  # type: ignore[attr-defined]


def test_a_seed_board_counts_iq_as_unknown_and_answers_nothing() -> None:
    board = Board()
    firmware = attach_firmware(board, identity=False)
    board.add_peripheral("motors", Motors())
    board.run_until(ms(1))
    assert ask(board, encode_message(IdentityQuery(1), 0)) == []
    assert firmware.stats.unknown == 1
    # and keeps working
    (echo,) = ask(board, encode_message(ParamSet(1, 0, 1, 5), 1))
    assert isinstance(echo, ParamAck) and echo.value == 5
    # a power cycle keeps what the firmware is (what was flashed)
    board.power_cycle()
    assert ask(board, encode_message(IdentityQuery(2), 0)) == []
