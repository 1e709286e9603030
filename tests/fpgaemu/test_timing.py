"""SPEC §7 on the emulated board: TsTimerPeriod = 1 ms at 1 MBd with TM every period while the
host sends RV every 1 ms and RE every 100 ms, for 10 s emulated; the board's timing report
against ``fpgalink.budget``'s arithmetic; and line rates that do not fit.

The timing report keeps a histogram, not a list: its median must still be exact."""

from __future__ import annotations

import statistics
from dataclasses import dataclass

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgaemu.timeline import CLOCK_HZ
from fpgaemu.timing import MISSED_LISTED, TimingReport
from fpgalink.protocol import Enable, FrameDecoder, References
from fpgalink.protocol.wire import (
    TM_CONTENT_BYTES,
    TM_TYPICAL_WIRE_BYTES,
    Flow,
    bytes_per_second,
    plan,
    wire_bytes,
)
from tests.support.emulated import MS, Cable


@dataclass
class Scenario:
    host: Cable
    periods: int
    tm_wire: list[int]  #: exact wire bytes of every TM the host received
    other_wire: int  #: wire bytes of every other frame the host received


def run_scenario(*, baud: int, period_ms: int, seconds: float, rv_every_ms: int | None = 1,
                 refs: tuple[float, float] = (45.0, -30.0)) -> Scenario:
    """The host's traffic is put on the line ahead of time, at exact cycles, in batches."""
    host = Cable.make(baud=baud, settings={"TsTimerPeriod": period_ms, "GetDataPeriodical": 1})
    decoder = FrameDecoder()
    scenario = Scenario(host, 0, [], 0)

    def collect() -> None:
        data = host.board.read_host_bytes()
        host.wire_bytes_read += len(data)
        for content in decoder.feed(data):
            assert isinstance(content, bytes)
            if content[:2] == b"TM":
                assert len(content) == TM_CONTENT_BYTES
                scenario.tm_wire.append(wire_bytes(content))
            else:
                scenario.other_wire += wire_bytes(content)

    batch_ms = 50
    end_ms = round(seconds * 1000)
    for first in range(0, end_ms, batch_ms):
        for ms in range(first, min(first + batch_ms, end_ms)):
            at = ms * MS + MS // 2  # between ticks
            if ms % 100 == 0:
                host.send(Enable(), at)
            if rv_every_ms is not None and ms % rv_every_ms == 0 and ms >= 10:
                host.send(References(*refs), at)
        host.board.run_until(min(first + batch_ms, end_ms) * MS)
        collect()
    # let the last period's TM finish, stopping short of the next tick
    host.board.run_until(end_ms * MS + period_ms * MS - 1)
    collect()
    scenario.periods = host.firmware.timing.periods
    return scenario


@pytest.fixture(scope="module")
def one_ms() -> Scenario:
    return run_scenario(baud=1_000_000, period_ms=1, seconds=10.0)


def test_no_period_misses_its_tm_over_10_s(one_ms: Scenario) -> None:
    timing = one_ms.host.firmware.timing
    assert timing.periods == 10_000
    assert timing.missed == []
    assert one_ms.host.firmware.stats.telemetry_sent == 10_000
    assert one_ms.host.firmware.stats.telemetry_dropped == 0
    assert len(one_ms.tm_wire) == timing.tm_finished == 10_000
    assert timing.worst_slack is not None and timing.worst_slack > 0
    # both wheels really moved under the RV stream, the board stayed enabled throughout
    fw = one_ms.host.firmware
    assert fw.channels[1].speed == pytest.approx(45.0, rel=0.01)
    assert fw.channels[2].speed == pytest.approx(-30.0, rel=0.01)
    assert fw.stats.references == 9_990
    assert one_ms.host.board.global_enable


def test_timing_report_counts_every_wire_byte_the_host_got(one_ms: Scenario) -> None:
    timing = one_ms.host.firmware.timing
    # what the board reports is exactly what arrived, and exactly the framing arithmetic
    assert timing.tx_wire_bytes == one_ms.host.wire_bytes_read
    assert timing.tx_wire_bytes == sum(one_ms.tm_wire) + one_ms.other_wire
    # TM: 52 content bytes + START + STOP + escapes
    assert min(one_ms.tm_wire) >= TM_CONTENT_BYTES + 2
    assert max(one_ms.tm_wire) <= 2 * TM_CONTENT_BYTES + 2


def test_reported_utilisation_matches_the_budget_arithmetic(one_ms: Scenario) -> None:
    timing = one_ms.host.firmware.timing
    period_s = 0.001
    capacity = bytes_per_second(1_000_000) * period_s
    assert capacity == 100
    per_period = timing.tx_wire_bytes / timing.periods
    mean_tm = statistics.fmean(one_ms.tm_wire)
    # about 55 wire bytes per TM: 54 + a few escapes
    assert 54.0 <= mean_tm <= TM_TYPICAL_WIRE_BYTES + 1
    report = plan(1_000_000, period_s, [
        Flow("TM", TM_CONTENT_BYTES, 1.0, escapes=1),
        Flow("E", 1, 1 / 300),
        Flow("RV", 18, 1.0, to_board=True),
        Flow("RE", 2, 1 / 100, to_board=True),
    ])
    assert report.fits
    utilisation = per_period / capacity
    assert utilisation == pytest.approx(report.to_host.utilisation, abs=0.015)
    assert utilisation == pytest.approx(0.55, abs=0.015)
    # host → board: what the board's receiver counted against the same arithmetic
    received = one_ms.host.board.uartread.stats.bytes_received / timing.periods
    assert received / capacity == pytest.approx(report.to_board.utilisation, abs=0.01)
    # The board's own report says the same.
    summary = one_ms.host.firmware.budget_report()
    assert summary["board_to_host_utilisation"] == pytest.approx(utilisation, abs=0.002)
    assert summary["host_to_board_utilisation"] == pytest.approx(received / capacity, abs=0.002)
    assert summary["missed_periods"] == 0 and summary["missed"] == []
    assert summary["median_slack_cycles"] == timing.median_slack
    assert summary["worst_slack_cycles"] == timing.worst_slack
    # slack: a TM leaves at its tick when the line is idle, so the median slack is the
    # period minus the TM's wire time
    median_tm = statistics.median(one_ms.tm_wire)
    assert timing.median_slack == (capacity - median_tm) * CLOCK_HZ // bytes_per_second(
        1_000_000)


def test_115200_baud_with_tm_every_1_ms_reports_misses() -> None:
    scenario = run_scenario(baud=115_200, period_ms=1, seconds=0.5, rv_every_ms=None)
    timing = scenario.host.firmware.timing
    report = plan(115_200, 0.001, [Flow("TM", TM_CONTENT_BYTES, 1.0, escapes=1)])
    assert not report.fits
    assert timing.periods == 500
    # one TM needs 4.7 ms of wire: at most one period in five gets its TM out at all
    assert len(scenario.tm_wire) < 0.25 * timing.periods
    assert len(timing.missed) >= timing.periods - len(scenario.tm_wire) - 10
    dropped = [m for m in timing.missed if m[1] is None]
    late = [m for m in timing.missed if m[1] is not None]
    assert dropped and late
    assert scenario.host.firmware.stats.telemetry_dropped == len(dropped)
    assert all(done - tick > MS for tick, done in late if done is not None)


@pytest.mark.parametrize(("period_ms", "fits"), [(4, False), (5, True)])
def test_115200_baud_fits_a_5_ms_period_and_not_a_4_ms_one(period_ms: int, fits: bool) -> None:
    # 54 wire bytes at 86.8 µs each = 4.69 ms: under 5 ms even with an E queued ahead
    scenario = run_scenario(baud=115_200, period_ms=period_ms, seconds=1.0, rv_every_ms=None)
    report = plan(115_200, period_ms / 1000, [Flow("TM", TM_CONTENT_BYTES, 1.0, escapes=1),
                                              Flow("E", 1, period_ms / 300)])
    assert report.fits == fits
    timing = scenario.host.firmware.timing
    assert (timing.missed == []) == fits
    if fits:
        assert len(scenario.tm_wire) == timing.periods
        assert timing.worst_slack is not None and timing.worst_slack > 0


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
