"""The event kernel: ordering, phases, cancellation, time bounds, seeded randomness."""

from __future__ import annotations

import functools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgaemu.timeline import CLOCK_HZ, Timeline, cycles_to_seconds, seconds_to_cycles


def test_events_run_in_cycle_order_ties_by_insertion() -> None:
    tl = Timeline()
    seen: list[tuple[str, int]] = []
    tl.schedule(50, lambda c: seen.append(("b", c)))
    tl.schedule(10, lambda c: seen.append(("a", c)))
    tl.schedule(50, lambda c: seen.append(("c", c)))
    tl.run_until(100)
    assert seen == [("a", 10), ("b", 50), ("c", 50)]
    assert tl.now == 100


def test_late_phase_runs_after_every_ordinary_event_of_the_cycle() -> None:
    tl = Timeline()
    seen: list[str] = []
    tl.schedule(5, lambda c: seen.append("late"), late=True)
    tl.schedule(5, lambda c: seen.append("early1"))
    # An ordinary event scheduled *during* the cycle still precedes the late phase.
    def schedule_early2(cycle: int) -> None:
        tl.schedule(cycle, lambda _: seen.append("early2"))

    tl.schedule(5, schedule_early2)
    tl.run_until(5)
    assert seen == ["early1", "early2", "late"]


def test_run_until_is_inclusive_and_jumps() -> None:
    tl = Timeline()
    seen: list[int] = []
    tl.schedule(10**12, seen.append)
    tl.run_until(10**12 - 1)
    assert seen == [] and tl.now == 10**12 - 1
    tl.run_until(10**12)
    assert seen == [10**12]


def test_cancel_and_next_deadline() -> None:
    tl = Timeline()
    seen: list[int] = []
    first = tl.schedule(10, seen.append)
    tl.schedule(20, seen.append)
    assert tl.next_deadline == 10
    first.cancel()
    assert tl.next_deadline == 20
    tl.run_until(30)
    assert seen == [20]
    assert tl.next_deadline is None


def test_now_during_event_is_the_event_cycle() -> None:
    tl = Timeline()
    seen: list[int] = []
    tl.schedule(7, lambda c: seen.append(tl.now))
    tl.run_until(9)
    assert seen == [7]


def test_no_time_travel() -> None:
    tl = Timeline()
    tl.run_until(100)
    with pytest.raises(ValueError):
        tl.schedule(99, lambda c: None)
    with pytest.raises(ValueError):
        tl.run_until(50)


def test_run_for_and_conversions() -> None:
    tl = Timeline()
    tl.run_for(0.3)
    assert tl.now == 30_000_000 == seconds_to_cycles(0.3)
    assert cycles_to_seconds(CLOCK_HZ) == 1.0


def test_rng_is_per_seed_and_per_consumer() -> None:
    a, b, c = Timeline(seed=1), Timeline(seed=1), Timeline(seed=2)
    assert a.rng("x").random() == b.rng("x").random()
    assert a.rng("x").random() != c.rng("x").random()
    assert a.rng("x").random() != a.rng("y").random()


@given(st.lists(st.tuples(st.integers(0, 1000), st.booleans()), max_size=40))
def test_order_matches_sorted_reference(items: list[tuple[int, bool]]) -> None:
    tl = Timeline()
    seen: list[int] = []
    for index, (cycle, late) in enumerate(items):
        tl.schedule(cycle, functools.partial(lambda i, _c: seen.append(i), index), late=late)
    tl.run_until(1000)
    expected = sorted(range(len(items)), key=lambda i: (items[i][0], items[i][1], i))
    assert seen == expected
