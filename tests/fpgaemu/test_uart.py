"""uartread / uartwrite: line-rate timing, queuing, and bit-level fault injection."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgaemu.board import Board
from fpgaemu.timeline import Timeline
from fpgaemu.uart import (
    BIT_START,
    BIT_STOP,
    ByteRun,
    LevelReceiver,
    LineFaults,
    SlotReceiver,
    UartRead,
    UartWrite,
    cycles_per_bit,
)
from tests.support.reference import naive_line_timing


def collect(faults: LineFaults | None = None, seed: int = 0) -> tuple[UartRead, list[ByteRun]]:
    runs: list[ByteRun] = []
    line = UartRead(Timeline(seed), runs.append, faults=faults)
    return line, runs


def timed(runs: list[ByteRun]) -> list[tuple[int, int]]:
    return [pair for run in runs for pair in run.timed()]


def test_divider() -> None:
    assert cycles_per_bit(1_000_000) == 100
    assert cycles_per_bit(115_200) == 868
    line, _ = collect()
    assert line.cycles_per_byte == 1_000


def test_idle_line_delivers_at_ten_bit_times() -> None:
    line, runs = collect()
    end = line.transmit(b"A", 500)
    assert timed(runs) == [(0x41, 1_500)] and end == 1_500


def test_bytes_written_faster_than_line_rate_queue() -> None:
    line, runs = collect()
    line.transmit(b"ab", 0)
    line.transmit(b"c", 10)  # the host wrote while "ab" was still on the wire
    line.transmit(b"d", 10_000)  # the line was idle again by then
    assert timed(runs) == [(97, 1_000), (98, 2_000), (99, 3_000), (100, 11_000)]


@given(st.lists(st.tuples(st.integers(0, 5_000), st.binary(min_size=1, max_size=8)),
                max_size=12))
def test_timing_matches_per_byte_reference(steps: list[tuple[int, bytes]]) -> None:
    line, runs = collect()
    writes: list[tuple[int, bytes]] = []
    cycle = 0
    for gap, data in steps:
        cycle += gap
        line.transmit(data, cycle)
        writes.append((cycle, data))
    assert timed(runs) == naive_line_timing(writes, 1_000)


@given(st.binary(min_size=1, max_size=20), st.data())
def test_a_flipped_data_bit_changes_exactly_one_byte(data: bytes, draw: st.DataObject) -> None:
    index = draw.draw(st.integers(0, len(data) - 1))
    bit = draw.draw(st.integers(0, 7))
    line, runs = collect(LineFaults(flip_bits={(index, 1 + bit)}))
    line.transmit(data, 0)
    got = timed(runs)
    expected = naive_line_timing([(0, data)], 1_000)
    assert len(got) == len(data)
    diffs = [k for k in range(len(data)) if got[k] != expected[k]]
    assert diffs == [index]
    assert got[index] == (data[index] ^ (1 << bit), expected[index][1])
    assert line.stats.bits_flipped == 1


@given(st.binary(min_size=1, max_size=20), st.data())
def test_a_broken_stop_bit_before_an_idle_line_drops_exactly_one_byte(
    data: bytes, draw: st.DataObject
) -> None:
    index = draw.draw(st.integers(0, len(data) - 1))
    line, runs = collect(LineFaults(break_stop={index}))
    line.transmit(data[:index + 1], 0)
    gap = line.line_free_at + 100  # one idle bit: the next start bit is a falling edge again
    line.transmit(data[index + 1:], gap)
    line._timeline.run_until(gap + 30_000)
    expected = naive_line_timing([(0, data[:index + 1]), (gap, data[index + 1:])], 1_000)
    assert timed(runs) == expected[:index] + expected[index + 1:]
    assert line.stats.framing_errors == 1


def test_a_broken_stop_bit_hides_the_next_start_bit_as_in_litex() -> None:
    # The stop bit reads low and the next start bit is low too: no falling edge, so the
    # receiver (like LiteX's RS232PHYRX, and unlike a level-triggered 16550) locks onto the
    # next edge inside the data. Outcomes from tests/fpgaemu/test_uart_hdl.py's reference.
    line, runs = collect(LineFaults(break_stop={0}))
    line.transmit(b"\x00AB", 0)
    line._timeline.run_until(10_000)
    assert timed(runs) == [(0xE8, 3_300)] and line.stats.framing_errors == 2


def test_level_triggered_a_broken_stop_bit_costs_the_next_byte_not_the_rest() -> None:
    # The same waveform with the level-triggered receiver (a 16550's, OpenTitan's): it hunts
    # again right after the low stop sample, finds the line low and starts at once, mid-bit;
    # that misframed byte fails too, and 0x42 arrives intact, in step. Outcomes from
    # tests/fpgaemu/test_uart_hdl.py's OpenTitan reference.
    runs: list[ByteRun] = []
    line = UartRead(Timeline(0), runs.append, faults=LineFaults(break_stop={0}),
                    rx_mode="level")
    line.transmit(b"\x00AB", 0)
    line._timeline.run_until(10_000)
    assert timed(runs) == [(0x42, 3_000)] and line.stats.framing_errors == 2


def test_level_triggered_a_break_is_a_framing_error_every_byte_time() -> None:
    ok = [(ord("o"), 9_000), (ord("k"), 10_000)]
    # Level-triggered, the byte begun in the break's last byte time reads the line's return
    # to idle as data: a stray 0xFC (as OpenTitan's receiver makes of it).
    for mode, errors, received in (("edge", 1, ok), ("level", 5, [(0xFC, 5_749), *ok])):
        runs: list[ByteRun] = []
        line = UartRead(Timeline(0), runs.append, faults=LineFaults(stuck=[(0, 5_000)]),
                        rx_mode=mode)
        line.transmit(b"\x55" * 5, 0)  # sent while the line is held low
        line.transmit(b"ok", 8_000)
        line._timeline.run_until(20_000)
        assert line.stats.framing_errors == errors, mode
        assert timed(runs) == received, mode


def test_an_unknown_receiver_mode_is_refused() -> None:
    with pytest.raises(ValueError, match="edge, level"):
        UartRead(Timeline(0), lambda run: None, rx_mode="fast")


def test_flip_stop_bit_by_index_is_a_framing_error() -> None:
    line, runs = collect(LineFaults(flip_bits={(1, BIT_STOP)}))
    line.transmit(b"xyz", 0)
    line._timeline.run_until(10_000)
    assert timed(runs) == [(ord("x"), 1_000), (0xEF, 3_300)]  # 'z' read from mid-data
    assert line.stats.framing_errors == 1


def test_a_flipped_start_bit_slips_then_resynchronises() -> None:
    # 0xFF then idle-looking data: with its start bit high, 0xFF's slots are all high, so the
    # receiver simply never sees it; the next byte is received normally.
    line, runs = collect(LineFaults(flip_bits={(0, BIT_START)}))
    line.transmit(b"\xffA", 0)
    assert timed(runs) == [(0x41, 2_000)]
    # 0x00 with a high start bit: the receiver starts at data bit 0, finds the next byte's
    # start bit where it wants a stop bit (framing error), then locks two bits late onto the
    # alternating 0x55 pattern; the last slipped byte is decided when the line has idled.
    line, runs = collect(LineFaults(flip_bits={(0, BIT_START)}))
    line.transmit(b"\x00" + b"U" * 4, 0)
    assert timed(runs) == [(0x55, 2_200), (0x55, 3_200), (0x55, 4_200)]
    line._timeline.run_until(5_200)
    assert timed(runs)[-1] == (0xD5, 5_200)
    assert line.stats.framing_errors == 1
    line.transmit(b"ok", 10_000)  # after idle, in step again
    assert timed(runs)[-2:] == [(ord("o"), 11_000), (ord("k"), 12_000)]


def test_noise_and_drops() -> None:
    line, runs = collect(LineFaults(noise={1: b"!?"}, drop={2}))
    line.transmit(b"abc", 0)
    assert timed(runs) == [(97, 1_000), (33, 2_000), (63, 3_000), (98, 4_000)]
    assert line.stats.noise_bytes == 2 and line.stats.dropped_bytes == 1
    assert line.line_free_at == 5_000  # noise took line time; the dropped byte too


def test_faults_only_touch_their_indexes_later_bursts_take_the_fast_path() -> None:
    line, runs = collect(LineFaults(flip_bits={(0, 1)}))
    line.transmit(b"\x00", 0)
    line.transmit(b"\x00", 0)
    assert timed(runs) == [(1, 1_000), (0, 2_000)]


def test_bit_error_rate_is_seeded() -> None:
    data = bytes(range(256)) * 4

    def run(seed: int) -> list[tuple[int, int]]:
        line, runs = collect(LineFaults(bit_error_rate=0.01), seed=seed)
        line.transmit(data, 0)
        return timed(runs)

    assert run(3) == run(3)
    assert run(3) != run(4)
    clean = naive_line_timing([(0, data)], 1_000)
    assert run(3) != clean


def test_uartwrite_drains_by_completion_cycle() -> None:
    tl = Timeline()
    tx = UartWrite(tl)
    tx.transmit(b"hello", 0)
    assert tx.read_completed(2_999) == b"he"
    assert tx.read_completed(3_000) == b"l"
    tl.run_until(10_000)
    assert tx.read_completed_timed() == [(108, 4_000), (111, 5_000)]
    assert tx.read_completed() == b""


def test_faults_on_the_tx_direction() -> None:
    board = Board(tx_faults=LineFaults(flip_bits={(1, 1)}))
    board.axi.write_tx(b"ab")
    board.axi.strobe_tx()
    board.run_for(0.001)
    assert board.read_host_bytes() == b"S`bP"  # 'a' (0x61) lost its bit 0


def _received(data: bytes, faults: LineFaults, cuts: list[int]) -> tuple[
        list[tuple[int, int]], int]:
    """``data`` written back to back, cut into writes at ``cuts``; what arrives, and the
    framing errors, once the line has idled."""
    line, runs = collect(faults)
    edges = [0, *sorted(set(cuts)), len(data)]
    for a, b in itertools.pairwise(edges):
        if b > a:
            line.transmit(data[a:b], 0)
    line._timeline.run_until(line.line_free_at + 20_000)
    return timed(runs), line.stats.framing_errors


@given(st.binary(min_size=1, max_size=24),
       st.lists(st.tuples(st.integers(0, 23), st.integers(0, 9)), max_size=6),
       st.lists(st.integers(0, 23), max_size=5), st.lists(st.integers(1, 23), max_size=6))
def test_what_arrives_depends_on_the_waveform_not_on_how_it_was_written(
    data: bytes, flips: list[tuple[int, int]], broken: list[int], cuts: list[int]
) -> None:
    faults = LineFaults(flip_bits={(i % len(data), b) for i, b in flips},
                        break_stop={i % len(data) for i in broken})
    whole = _received(data, faults, [])
    assert _received(data, LineFaults(flip_bits=set(faults.flip_bits),
                                      break_stop=set(faults.break_stop)), cuts) == whole


@pytest.mark.parametrize("receiver_type", [SlotReceiver, LevelReceiver])
@given(st.lists(st.sampled_from([0, 1]), min_size=1, max_size=120),
       st.lists(st.integers(1, 119), max_size=8))
def test_the_receiver_is_a_function_of_the_slots(receiver_type: type[SlotReceiver],
                                                 slots: list[int], cuts: list[int]) -> None:
    def receive(pieces: list[tuple[int, list[int]]]) -> tuple[list[tuple[int, int]], int]:
        receiver = receiver_type(100)
        out: list[tuple[int, int]] = []
        for start, piece in pieces:
            receiver.add(start, piece)
            out += receiver.decide(start + len(piece) * 100)  # what is known so far
        out += receiver.decide(10**9)  # then the line idles
        return out, receiver.framing_errors

    whole = receive([(0, slots)])
    edges = [0, *sorted({c for c in cuts if c < len(slots)}), len(slots)]
    pieces = [(a * 100, slots[a:b]) for a, b in itertools.pairwise(edges) if b > a]
    assert receive(pieces) == whole
    # An idle stretch may as well be a pause between two writes.
    spaced: list[tuple[int, list[int]]] = []
    for start, piece in pieces:
        while piece and piece[-1] == 1:
            piece = piece[:-1]
        if piece:
            spaced.append((start, piece))
    assert receive(spaced) == whole
