"""A board paced in its host's process does not run past a deadline its host has not met
(fpgaemu.serving.hosts): driven by a fake clock, no sleeping."""

from __future__ import annotations

import pytest

from fpgaemu.build import build_board
from fpgaemu.serve import PacedBoard
from fpgaemu.serving.hosts import HOST_LATE_S, HOST_TURN_S, HOST_WAIT_MAX_S, HostDeadlines


def test_the_earliest_deadline_that_came_is_waited_for_and_only_for_so_long() -> None:
    now = [10.0]
    hosts = HostDeadlines(lambda: now[0])
    assert hosts.overdue() is None  # no host
    dues: dict[str, float | None] = {"L": 10.5, "R": None}
    hosts.follow("L", lambda: dues["L"])
    hosts.follow("R", lambda: dues["R"])
    assert hosts.overdue() is None  # not come yet
    now[0] = 11.0
    dues["R"] = 10.8
    assert hosts.overdue() == 10.5  # the earliest of those that came
    dues["L"] = 10.6  # L met it: the next
    assert hosts.overdue() == 10.6
    assert hosts.overdue(10.6) is None  # at a reading of the clock given: not come
    assert hosts.overdue(10.6 + HOST_LATE_S / 2) is None  # a loop turn late: not waited for
    # One never met is not waited for beyond HOST_WAIT_MAX_S of the clock.
    now[0] += HOST_WAIT_MAX_S / 2
    assert hosts.overdue() == 10.6
    now[0] += HOST_WAIT_MAX_S
    assert hosts.overdue() is None
    hosts.forget("L")
    hosts.forget("R")
    assert hosts.overdue() is None


def test_a_board_waits_at_its_hosts_overdue_deadline_and_trails_from_it() -> None:
    now = [5.0]
    paced = PacedBoard(build_board(), clock=lambda: now[0])
    due: list[float | None] = [5.1]
    paced.hosts.follow("host", lambda: due[0])
    now[0] = 5.3  # the process was not scheduled: the host's 5.1 went by unmet
    paced.run()
    assert paced.board.now == paced.target_cycle(5.1)
    assert paced.behind() == pytest.approx(0.2)
    # It looks again after the host's turn, not at once.
    wake = paced.next_wake()
    assert wake is not None and wake >= now[0] + HOST_TURN_S
    due[0] = 5.2  # the host met it: on to its next
    paced.run()
    assert paced.board.now <= paced.target_cycle(5.2)
    due[0] = 5.4
    while paced.board.now < paced.target_cycle():
        paced.run()
    assert paced.behind() == 0.0
    assert paced.board.now == paced.target_cycle(5.3)  # caught up, as if never held
