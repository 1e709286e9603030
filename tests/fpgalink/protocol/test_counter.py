"""Counter tracking (SPEC §4): gaps, duplicates and reordering, across the 99999 wrap."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from fpgalink.protocol import CounterTracker, Observation, SendCounter


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


def test_one_corrupted_counter_does_not_wreck_the_sequence() -> None:
    t = CounterTracker()
    for c in range(100):
        t.observe(c)
    # Message 100 arrives with a damaged counter (no checksum protects it).
    assert t.observe(47_100) is Observation.SUSPECT
    assert t.observe(101) is Observation.CORRUPT
    for c in range(102, 200):
        assert t.observe(c) is Observation.IN_ORDER
    assert (t.lost, t.duplicates, t.corrupted) == (0, 0, 1)


def test_a_real_long_outage_is_believed_on_the_next_counter() -> None:
    t = CounterTracker()
    t.observe(10)
    assert t.observe(5_011) is Observation.SUSPECT
    assert t.observe(5_012) is Observation.GAP
    assert t.lost == 5_000 and t.corrupted == 0
    assert t.observe(5_013) is Observation.IN_ORDER
    # A damaged counter that lands in the past is a duplicate, then the sequence goes on.
    assert t.observe(3) is Observation.DUPLICATE
    assert t.observe(5_014) is Observation.IN_ORDER


def test_suspect_then_a_small_gap_counts_the_gap_and_the_corruption() -> None:
    t = CounterTracker()
    t.observe(0)
    assert t.observe(60_000 - 10_000) is Observation.SUSPECT
    assert t.observe(4) is Observation.GAP  # 1, 2, 3 lost
    assert (t.lost, t.corrupted) == (3, 1)


def test_late_arrivals_are_recognised_across_many_laps() -> None:
    t = CounterTracker()
    value = SendCounter(99_990)
    for _ in range(3):  # three laps of the counter space
        for _ in range(100_000 - 3):
            t.observe(value.take())
        skipped = [value.take(), value.take()]
        t.observe(value.take())
        assert t.observe(skipped[1]) is Observation.LATE
        assert t.observe(skipped[1]) is Observation.DUPLICATE
        assert t.observe(skipped[0]) is Observation.LATE
    assert (t.lost, t.late, t.duplicates) == (0, 6, 3)


def test_a_missing_counter_is_remembered_for_the_window_only() -> None:
    t = CounterTracker()
    t.observe(0)
    t.observe(2)  # 1 missing
    for c in range(3, 3 + 4094):
        t.observe(c)
    assert t.observe(1) is Observation.LATE  # 4,096 behind: still in the window
    t2 = CounterTracker()
    t2.observe(0)
    t2.observe(2)
    for c in range(3, 3 + 4095):
        t2.observe(c)
    assert t2.observe(1) is Observation.DUPLICATE  # 4,097 behind: forgotten
    assert t2.lost == 1


def test_every_counter_sequence_costs_constant_work_per_message() -> None:
    # 2,000 messages whose counters jump by 999 each: the missing ones used to be trimmed
    # one entry at a time (3.2 ms a message). Count the tracker's calls, not its time.
    import cProfile
    import pstats

    t = CounterTracker()
    jumps = [(k * 999) % 100_000 for k in range(2000)]
    profile = cProfile.Profile()
    profile.enable()
    for counter in jumps:
        t.observe(counter)
    profile.disable()
    calls = pstats.Stats(profile).total_calls  # type: ignore[attr-defined]
    assert calls < 20 * len(jumps), f"{calls} calls for {len(jumps)} messages"
    assert t.skipped == 998 * 1999 and t.duplicates == 0
