"""uartsend: framing equals fpgalink's encoder, exact line-rate timing, busy and refusal."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgaemu.axi import TxQueue
from fpgaemu.board import Board
from fpgaemu.uartsend import TxDone
from fpgalink.protocol.framing import Framing, encode_frame


@st.composite
def framings(draw: st.DrawFn) -> Framing:
    start, stop, skip = draw(st.lists(st.integers(0, 255), min_size=3, max_size=3,
                                      unique=True))
    return Framing(start=start, stop=stop, skip=skip)


@given(st.binary(max_size=200), framings(), st.integers(0, 10_000))
def test_wire_bytes_and_timing(content: bytes, framing: Framing, at: int) -> None:
    board = Board(framing=framing)
    board.run_until(at)
    board.axi.write_tx(content)
    assert board.axi.strobe_tx()
    board.run_for(0.01)
    wire = encode_frame(content, framing)
    got = board.read_host_bytes_timed()
    assert bytes(b for b, _ in got) == wire
    assert [c for _, c in got] == [at + 1_000 * (i + 1) for i in range(len(wire))]


@given(st.lists(st.tuples(st.binary(max_size=40), st.integers(0, 8_000)),
                max_size=8))
def test_send_tx_is_write_tx_then_strobe_tx(steps: list[tuple[bytes, int]]) -> None:
    # The firmware's one call against its two, idle or busy, with a fault hook losing some
    # frames: the same RAM, registers, counters, hook calls and wire, cycle for cycle.
    boards = (Board(), Board())
    seen: tuple[list[tuple[bytes, int]], list[tuple[bytes, int]]] = ([], [])
    results: tuple[list[bool], list[bool]] = ([], [])
    for fused, board in enumerate(boards):
        def keep(content: bytes, cycle: int, seen: list[tuple[bytes, int]] = seen[fused]
                 ) -> bool:
            seen.append((content, cycle))
            return len(content) % 3 != 1
        board.uartsend.frame_filter = keep
        for content, delay in steps:
            board.run_for(delay / 100e6)
            if fused:
                results[fused].append(board.axi.send_tx(content))
            else:
                board.axi.write_tx(content)
                results[fused].append(board.axi.strobe_tx())
        board.run_for(0.01)
    plain, fused_board = boards
    assert results[0] == results[1] and seen[0] == seen[1]
    assert plain.uartsend.stats == fused_board.uartsend.stats
    assert plain.uartsend.length == fused_board.uartsend.length
    assert plain.blk_mem_gen_tx.read_bytes(0, 64) == fused_board.blk_mem_gen_tx.read_bytes(0, 64)
    assert plain.read_host_bytes_timed() == fused_board.read_host_bytes_timed()


def test_send_tx_of_more_than_the_ram_holds_changes_nothing() -> None:
    board = Board()
    with pytest.raises(IndexError, match="outside"):
        board.axi.send_tx(b"x" * (board.blk_mem_gen_tx.size + 1))
    assert (board.uartsend.length, board.uartsend.stats.frames, board.axi.tx_busy) == (
        0, 0, False)


def test_words_written_by_the_processor_are_sent_little_endian() -> None:
    board = Board()
    board.axi.write_tx_word(0, int.from_bytes(b"PSab", "little"))
    board.uartsend.set_length(3)
    board.axi.strobe_tx()
    board.run_for(0.001)
    assert board.read_host_bytes() == b"S\\P\\SaP"


def test_a_strobe_while_busy_is_refused_and_counted() -> None:
    board = Board()
    done: list[TxDone] = []
    board.axi.on_tx_done(done.append)
    board.axi.write_tx(b"abc")  # 5 wire bytes: busy for 5,000 cycles
    assert board.axi.strobe_tx()
    board.run_until(4_999)
    assert board.axi.tx_busy
    assert not board.axi.strobe_tx()
    assert board.uartsend.stats.refused_strobes == 1
    board.run_until(5_000)
    assert not board.axi.tx_busy
    assert done == [TxDone(5_000, 5)]
    assert board.axi.strobe_tx()
    board.run_for(0.001)
    assert board.read_host_bytes() == b"SabcP" * 2


def test_writing_the_ram_while_busy_is_counted() -> None:
    board = Board()
    board.axi.write_tx(b"abc")
    board.axi.strobe_tx()
    board.axi.write_tx(b"xyz")
    assert board.uartsend.stats.writes_while_busy == 1
    board.run_for(0.001)
    assert board.read_host_bytes() == b"SabcP"


def test_firmware_queue_sends_back_to_back() -> None:
    board = Board()
    queue = TxQueue(board.axi, depth=2)
    assert queue.send(b"one") and queue.send(b"two") and queue.send(b"three")
    assert not queue.send(b"four")  # depth 2 behind the one on the wire
    board.run_for(0.001)
    got = board.read_host_bytes_timed()
    wire = b"SoneP" + b"StwoP" + b"SthreeP"
    assert bytes(b for b, _ in got) == wire
    assert [c for _, c in got] == [1_000 * (i + 1) for i in range(len(wire))]
    assert queue.stats.dropped == 1 and queue.stats.sent == 3


def test_other_baud_rates() -> None:
    board = Board(baud=115_200)
    board.axi.write_tx(b"E")
    board.axi.strobe_tx()
    board.run_for(0.001)
    assert [c for _, c in board.read_host_bytes_timed()] == [8_680, 17_360, 26_040]
