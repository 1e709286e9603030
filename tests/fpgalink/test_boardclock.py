"""Board time onto host time: anchored once, then advanced by board time alone (a burst
keeps its true spacing), across the u32 wrap, and anchored again after a board restart."""

from __future__ import annotations

from fpgalink.boardclock import BOARD_CLOCK_WRAP_US, BoardClock


def test_a_burst_keeps_the_boards_spacing() -> None:
    clock = BoardClock()
    assert clock.ns(5_000, 1_000_000_000) == 1_000_000_000
    # three samples read at one host instant, 1 ms apart on the board
    assert [clock.ns(t, 2_000_000_000) for t in (6_000, 7_000, 8_000)] == [
        1_001_000_000, 1_002_000_000, 1_003_000_000]


def test_the_wrap_continues_the_time() -> None:
    clock = BoardClock()
    start = BOARD_CLOCK_WRAP_US - 500
    clock.ns(start, 0)
    assert clock.ns(500, 0) == 1_000_000  # 1 ms later, across the wrap
    assert clock.seconds(1_500, 0.0) == 0.002


def test_a_restart_anchors_again() -> None:
    clock = BoardClock()
    clock.ns(10_000_000, 0)
    assert clock.ns(10_001_000, 0) == 1_000_000
    # back to near zero: the board restarted; now is the new anchor
    assert clock.ns(2_000, 50_000_000_000) == 50_000_000_000
    assert clock.ns(3_000, 99) == 50_001_000_000
