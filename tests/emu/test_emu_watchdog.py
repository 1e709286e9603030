"""global_enable: RE raises it, RD drops it in its STOP cycle, the 300 ms watchdog is an
exact deadline counted from the STOP of the last RE."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from fpgaemu.board import Board
from fpgaemu.uartcommand import WATCHDOG_CYCLES, EnableCause, EnableChange
from models import NaiveUartCommand, naive_line_timing

RE, RD = b"SREP", b"SRDP"


def watch(board: Board) -> list[EnableChange]:
    changes: list[EnableChange] = []
    board.axi.on_global_enable(changes.append)
    return changes


def test_watchdog_constant_is_300_ms_of_the_clock() -> None:
    assert WATCHDOG_CYCLES == 30_000_000


def test_enable_falls_exactly_300_ms_after_the_last_re_stop() -> None:
    board = Board()
    changes = watch(board)
    stop = board.host_write(RE, 12_345)
    assert stop == 12_345 + 4_000
    board.run_until(stop - 1)
    assert not board.global_enable
    board.run_until(stop)
    assert board.global_enable
    board.run_until(stop + WATCHDOG_CYCLES - 1)
    assert board.global_enable
    board.run_until(stop + WATCHDOG_CYCLES)
    assert not board.global_enable
    assert changes == [
        EnableChange(stop, True, EnableCause.ENABLE),
        EnableChange(stop + WATCHDOG_CYCLES, False, EnableCause.WATCHDOG),
    ]


def test_re_every_299_ms_keeps_it_high_for_10_s() -> None:
    board = Board()
    changes = watch(board)
    period = 29_900_000
    last = 0
    for k in range(34):  # 34 × 299 ms ≈ 10.2 s
        last = board.host_write(RE, k * period)
        board.run_until(k * period + period // 2)
    assert board.now >= 10 * 100_000_000
    assert board.global_enable
    assert changes == [EnableChange(4_000, True, EnableCause.ENABLE)]
    board.run_until(last + WATCHDOG_CYCLES)
    assert changes[-1] == EnableChange(last + WATCHDOG_CYCLES, False, EnableCause.WATCHDOG)


def test_rd_drops_it_in_the_cycle_it_completes_and_disarms_the_watchdog() -> None:
    board = Board()
    changes = watch(board)
    board.host_write(RE, 0)
    rd_stop = board.host_write(RD, 1_000_000)
    board.run_until(rd_stop - 1)
    assert board.global_enable
    board.run_until(rd_stop)
    assert not board.global_enable
    assert board.uartcommand.watchdog_deadline is None
    board.run_for(1.0)
    assert changes == [
        EnableChange(4_000, True, EnableCause.ENABLE),
        EnableChange(rd_stop, False, EnableCause.DISABLE),
    ]


def test_a_lapsed_watchdog_is_rearmed_by_the_next_re() -> None:
    board = Board()
    changes = watch(board)
    board.host_write(RE, 0)
    board.run_for(0.5)
    assert not board.global_enable
    again = board.host_write(RE)
    board.run_until(again)
    assert board.global_enable
    assert board.uartcommand.watchdog_deadline == again + WATCHDOG_CYCLES
    board.run_until(again + WATCHDOG_CYCLES)
    assert not board.global_enable
    assert [c.enabled for c in changes] == [True, False, True, False]


def test_an_re_completing_in_the_lapse_cycle_keeps_enable_high() -> None:
    board = Board()
    changes = watch(board)
    first = board.host_write(RE, 0)
    board.host_write(RE, first + WATCHDOG_CYCLES - 4_000)
    board.run_until(first + 2 * WATCHDOG_CYCLES)
    assert [(c.cycle, c.enabled) for c in changes] == [
        (first, True), (first + 2 * WATCHDOG_CYCLES, False)
    ]


def test_re_inside_a_burst_is_timed_by_its_own_stop() -> None:
    board = Board()
    changes = watch(board)
    board.host_write(b"SabcP" + RE + b"SxyzP", 0)
    board.run_for(0.001)
    assert changes[0].cycle == 9_000


@given(st.lists(st.tuples(st.integers(0, 45_000_000), st.sampled_from([RE, RD, b"SxP"])),
                max_size=8))
def test_edges_match_the_per_byte_model(steps: list[tuple[int, bytes]]) -> None:
    board = Board()
    changes = watch(board)
    writes: list[tuple[int, bytes]] = []
    cycle = 0
    for gap, data in steps:
        cycle += gap
        board.host_write(data, cycle)
        writes.append((cycle, data))
    end = cycle + 10 * WATCHDOG_CYCLES
    board.run_until(end)
    model = NaiveUartCommand()
    timed = naive_line_timing(writes, 1_000)
    model.feed(timed)
    model.finish(end)
    assert [(c.cycle, c.enabled) for c in changes] == model.enable
