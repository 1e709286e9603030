"""Counter tracking (SPEC §4): gaps, duplicates and reordering, across the 99999 wrap."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from fpgalink import CounterTracker, Observation, SendCounter


def test_send_counter_wraps() -> None:
    counter = SendCounter(99_998)
    assert [counter.take() for _ in range(4)] == [99_998, 99_999, 0, 1]


def test_gap_duplicate_and_late_across_the_wrap() -> None:
    t = CounterTracker()
    assert t.observe(99_997) is Observation.FIRST
    assert t.observe(99_998) is Observation.IN_ORDER
    assert t.observe(1) is Observation.GAP  # 99999 and 0 skipped
    assert t.last_gap == 2 and t.lost == 2
    assert t.observe(0) is Observation.LATE
    assert t.lost == 1
    assert t.observe(1) is Observation.DUPLICATE
    assert t.observe(2) is Observation.IN_ORDER
    assert (t.skipped, t.late, t.duplicates, t.received) == (2, 1, 1, 6)


@given(
    st.integers(0, 99_999),
    st.lists(st.tuples(st.sampled_from(["ok", "drop", "dup"]), st.booleans()), max_size=300),
)
def test_counts_are_exact(start: int, script: list[tuple[str, bool]]) -> None:
    sent = SendCounter(start)
    tracker = CounterTracker()
    confirmed_drops = unseen_drops = duplicated = delivered = 0
    started = False
    for action, _ in script:
        value = sent.take()
        if action == "drop" and started:
            unseen_drops += 1
            continue
        tracker.observe(value)
        started = True
        delivered += 1
        # A drop shows only when the next message arrives.
        confirmed_drops += unseen_drops
        unseen_drops = 0
        if action == "dup":
            tracker.observe(value)
            duplicated += 1
    assert tracker.lost == confirmed_drops
    assert tracker.duplicates == duplicated
    assert tracker.received == delivered + duplicated
