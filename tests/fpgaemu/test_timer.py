"""The timer peripheral: interrupts every period, a new period from the next tick."""

from __future__ import annotations

import pytest

from fpgaemu.timeline import Timeline, ms
from fpgaemu.timer import Timer


def test_timer_interrupts_every_period_from_its_start() -> None:
    timeline = Timeline()
    timer = Timer(timeline, 1)
    ticks: list[int] = []
    timer.on_interrupt(ticks.append)
    assert timer.period_cycles == 100_000 and Timer(timeline, 1000).period_cycles == ms(1000)
    timeline.run_until(5)
    timer.start(5)
    timeline.run_until(ms(3) + 5)
    assert ticks == [100_005, 200_005, 300_005]
    assert timer.ticks == 3 and timer.next_tick == 400_005


def test_new_period_takes_effect_from_the_next_tick() -> None:
    timeline = Timeline()
    timer = Timer(timeline, 1)
    ticks: list[int] = []
    timer.on_interrupt(ticks.append)
    timer.start(0)
    timer.set_period_ms(20)  # the running count is not cut short
    timeline.run_until(ms(50))
    assert ticks == [ms(1), ms(21), ms(41)]


def test_a_period_written_in_the_interrupt_counts_from_that_tick() -> None:
    timeline = Timeline()
    timer = Timer(timeline, 1)
    ticks: list[int] = []

    def handler(cycle: int) -> None:
        ticks.append(cycle)
        if len(ticks) == 2:
            timer.set_period_ms(5)

    timer.on_interrupt(handler)
    timer.start(0)
    timeline.run_until(ms(12))
    assert ticks == [ms(1), ms(2), ms(7), ms(12)]


@pytest.mark.parametrize("bad", [0, 1001, -1])
def test_timer_refuses_periods_outside_the_parameter_range(bad: int) -> None:
    with pytest.raises(ValueError):
        Timer(Timeline(), bad)
    with pytest.raises(ValueError):
        Timer(Timeline(), 1).set_period_ms(bad)
