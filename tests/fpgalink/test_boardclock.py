"""Board time onto host time, estimated from every sample: a burst keeps its true spacing,
the first sample's delay is worked off, a board clock running 100 ppm fast is tracked (an
anchor taken once is 12 ms off after two minutes), stamps stay in order whatever the
delays, across the u32 wrap, and a board restart starts the mapping again."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fpgalink.boardclock import BOARD_CLOCK_WRAP_US, MAX_SLEW, BoardClock

WIRE_NS = 540_000  #: a TM's time on the wire at 1 MBd: the smallest delay


def test_a_burst_keeps_the_boards_spacing() -> None:
    clock = BoardClock()
    assert clock.ns(5_000, 1_000_000_000) == 1_000_000_000
    # three samples read at one host instant, 1 ms apart on the board
    assert [clock.ns(t, 1_900_000_000) for t in (6_000, 7_000, 8_000)] == [
        1_001_000_000, 1_002_000_000, 1_003_000_000]


def test_the_wrap_continues_the_time() -> None:
    clock = BoardClock()
    start = BOARD_CLOCK_WRAP_US - 500
    clock.ns(start, 10_000_000)
    assert clock.ns(500, 11_500_000) == 11_000_000  # 1 ms later, across the wrap
    assert clock.seconds(1_500, 0.0125) == 0.012


def test_a_restart_starts_the_mapping_again_from_its_first_sample() -> None:
    clock = BoardClock()
    clock.ns(10_000_000, 0)
    assert clock.ns(10_001_000, 2_000_000) == 1_000_000
    # back to near zero: the board restarted; its first sample is the new reference
    assert clock.ns(2_000, 50_000_000_000) == 50_000_000_000
    assert clock.ns(3_000, 50_009_000_000) == 50_001_000_000
    assert clock.anchors == 2


def _run(ppm: float, seconds: float, first_delay_ns: int = WIRE_NS, seed: int = 1
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, BoardClock]:
    """A board sampling every 1 ms of its own time, its clock ``ppm`` fast; each sample
    reaches the host after the wire time plus a random delay, and for 0.3 s every 7 s the
    host is stalled (what arrived meanwhile is read at the stall's end). Returns the true
    sampling instants on the host clock, the arrival times and the stamps."""
    rng = np.random.default_rng(seed)
    board_us = np.arange(0, int(seconds * 1e6), 1000, dtype=np.int64)
    true_ns = 5_000_000_000 + (board_us * 1000 / (1 + ppm * 1e-6)).astype(np.int64)
    delay = WIRE_NS + rng.exponential(300_000, len(board_us)).astype(np.int64)
    delay[0] = first_delay_ns
    arrival = true_ns + delay
    for stall in np.arange(7e9, seconds * 1e9, 7e9):
        start, end = 5e9 + stall, 5e9 + stall + 3e8
        arrival = np.where((arrival >= start) & (arrival < end), int(end), arrival)
    arrival = np.maximum.accumulate(arrival)  # read in order
    clock = BoardClock()
    stamps = np.array([clock.ns(int(u) % BOARD_CLOCK_WRAP_US, int(a))
                       for u, a in zip(board_us, arrival, strict=True)], dtype=np.int64)
    return true_ns, arrival, stamps, clock


def test_a_board_clock_100_ppm_fast_is_tracked() -> None:
    true_ns, _, stamps, clock = _run(ppm=100.0, seconds=120.0)
    error_us = (stamps - true_ns - WIRE_NS) / 1000
    settled = error_us[20_000:]  # after 20 s: the drift is estimated from 10 s on
    assert abs(clock.drift_ppm - 100.0) < 2.0, clock.drift_ppm
    assert np.max(np.abs(settled)) < 150, (settled.min(), settled.max())
    # An anchor taken once, advanced by board time alone, is off by the drift: 12 ms.
    anchored_once = true_ns[0] + WIRE_NS + (np.arange(len(true_ns)) * 1_000_000)
    assert abs((anchored_once[-1] - true_ns[-1] - WIRE_NS) / 1000) > 11_000


def test_a_slow_board_clock_too() -> None:
    true_ns, _, stamps, clock = _run(ppm=-60.0, seconds=60.0, seed=4)
    assert abs(clock.drift_ppm + 60.0) < 3.0, clock.drift_ppm
    assert np.max(np.abs((stamps - true_ns - WIRE_NS)[20_000:])) < 150_000


def test_the_first_samples_delay_is_worked_off_within_half_a_second() -> None:
    true_ns, _, stamps, _ = _run(ppm=0.0, seconds=5.0, first_delay_ns=80_000_000)
    error_us = (stamps - true_ns - WIRE_NS) / 1000
    assert error_us[0] > 79_000  # the first stamp is when it arrived
    assert np.max(np.abs(error_us[500:])) < 100  # 80 ms at 25 % of board time: 0.32 s
    assert np.min(np.diff(stamps)) >= (1 - MAX_SLEW) * 1_000_000 - 1


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 20_000), st.integers(0, 50_000_000)),
                min_size=2, max_size=300))
def test_stamps_keep_their_order_whatever_the_delays(
        steps: list[tuple[int, int]]) -> None:
    # Samples taken ever later on the board, arriving in order after any delay.
    clock = BoardClock()
    board, taken, arrived = 0, 0, 0
    previous = None
    for spacing_us, delay_ns in steps:
        board += spacing_us
        taken += spacing_us * 1000
        arrived = max(arrived, taken + delay_ns)
        stamp = clock.ns(board, arrived)
        if previous is not None:
            assert stamp - previous >= (1 - MAX_SLEW) * spacing_us * 1000 - 1
        previous = stamp


def test_a_restart_said_by_the_link_starts_again_keeping_the_drift() -> None:
    _, _, _, clock = _run(ppm=100.0, seconds=30.0)
    drift = clock.drift_ppm
    clock.restart()
    assert not clock.anchored
    # The restarted board's clock is ahead of where the old one was: no jump back to see.
    assert clock.ns(40_000_000, 90_000_000_000) == 90_000_000_000
    assert clock.anchors == 2 and clock.drift_ppm == drift
