"""The timing report keeps a histogram, not a list: its median must still be exact."""

from __future__ import annotations

import statistics

from hypothesis import given
from hypothesis import strategies as st

from fpgaemu.firmware import MISSED_LISTED, TimingReport


@given(st.lists(st.integers(-5_000, 100_000), min_size=1, max_size=200))
def test_median_and_worst_slack_are_exact(slacks: list[int]) -> None:
    report = TimingReport()
    for slack in slacks:
        report.record_slack(0, 0, slack)
    assert report.median_slack == statistics.median(slacks)
    assert report.worst_slack == min(slacks)
    assert report.missed_count == sum(s < 0 for s in slacks)


def test_missed_list_is_bounded_but_every_miss_counted() -> None:
    report = TimingReport()
    for tick in range(MISSED_LISTED + 50):
        report.record_miss(tick, None)
    assert len(report.missed) == MISSED_LISTED
    assert report.missed_count == MISSED_LISTED + 50
    assert report.median_slack is None and report.worst_slack is None
