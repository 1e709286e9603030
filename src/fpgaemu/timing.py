"""The board's own timing report (SPEC §7): how its output fitted its timer periods.

The firmware records, for every period, whether its ``TM`` left the wire before the next
tick and with how much slack; :meth:`TimingReport.summary` adds the line utilisation per
direction. Slack is kept as a histogram of exact values (a handful of distinct values in
practice) and missed periods as a bounded list, so memory stays flat however long the
board runs.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final

if TYPE_CHECKING:
    from fpgaemu.board import Board

__all__ = ["MISSED_LISTED", "FrameBooking", "TimingReport"]

#: Missed periods listed individually (later ones are only counted), so a long run under
#: overload keeps bounded memory.
MISSED_LISTED: Final = 10_000


@dataclass(slots=True)
class TimingReport:
    periods: int = 0
    tm_finished: int = 0
    slack_histogram: Counter[int] = field(default_factory=Counter)
    #: (tick cycle, cycle the TM's last byte ended or None if it was never sent), first
    #: ``MISSED_LISTED`` of them
    missed: list[tuple[int, int | None]] = field(default_factory=list)
    missed_count: int = 0
    tx_wire_bytes: int = 0
    started_cycle: int = 0

    def record_slack(self, tick: int, done: int, slack: int) -> None:
        self.tm_finished += 1
        self.slack_histogram[slack] += 1
        if slack < 0:
            self.record_miss(tick, done)

    def record_miss(self, tick: int, done: int | None) -> None:
        self.missed_count += 1
        if len(self.missed) < MISSED_LISTED:
            self.missed.append((tick, done))

    @property
    def median_slack(self) -> float | None:
        if not self.tm_finished:
            return None
        values = sorted(self.slack_histogram.items())
        middle = (self.tm_finished - 1) / 2
        low = high = None
        seen = 0
        for value, count in values:
            if low is None and seen + count > int(middle):
                low = value
            if seen + count > math.ceil(middle):
                high = value
                break
            seen += count
        assert low is not None and high is not None
        return (low + high) / 2

    @property
    def worst_slack(self) -> int | None:
        return min(self.slack_histogram) if self.slack_histogram else None

    def summary(self, board: Board) -> dict[str, Any]:
        """SPEC §7 for the run so far: line utilisation per direction since power-up, slack
        per period (cycles from a TM's last stop bit to the next tick), missed periods."""
        elapsed = board.now - self.started_cycle
        # Each direction at its own byte spacing (uartwrite may leave a gap after a byte).
        tx_capacity = elapsed / board.uartwrite.byte_step if elapsed > 0 else 0.0
        rx_capacity = elapsed / board.uartread.byte_step if elapsed > 0 else 0.0
        return {
            "periods": self.periods,
            "board_to_host_utilisation": (
                self.tx_wire_bytes / tx_capacity if tx_capacity else 0.0
            ),
            "host_to_board_utilisation": (
                board.uartread.stats.bytes_received / rx_capacity if rx_capacity else 0.0
            ),
            "median_slack_cycles": self.median_slack,
            "worst_slack_cycles": self.worst_slack,
            "missed_periods": self.missed_count,
            "missed": list(self.missed),
        }


class FrameBooking:
    """The frames on the TX wire, oldest first, each booked into :attr:`report` (its wire
    bytes, a ``TM``'s slack to the next tick) once its last stop bit has ended. The wire has
    no event at a frame's end, so the firmware books what has ended before anything reads
    the report or changes the timer period, and at each tick: each frame is booked as it
    would have been at its end."""

    def __init__(self) -> None:
        self.report = TimingReport()
        #: (done cycle, wire bytes, tick or None) of each frame on the wire
        self._on_wire: deque[tuple[int, int, int | None]] = deque()

    def started(self, tick: int | None, done: int, wire_bytes: int) -> None:
        """A frame of ``wire_bytes`` went onto the wire, its last stop bit ending at
        ``done``; ``tick``: the timer interrupt whose ``TM`` it is (``None``: no ``TM``)."""
        self._on_wire.append((done, wire_bytes, tick))

    def due(self, now: int) -> bool:
        """Whether a frame has ended by ``now`` and is not booked yet."""
        on_wire = self._on_wire
        return bool(on_wire) and on_wire[0][0] <= now

    def report_at(self, board: Board) -> TimingReport:
        """The report with every frame ended by the board's present cycle booked."""
        self.book(board.now, board.timer.period_cycles)
        return self.report

    def book(self, now: int, period: int) -> None:
        """Book every frame ended by ``now``, a ``TM``'s slack against the timer ``period``
        (cycles) in force."""
        on_wire = self._on_wire
        report = self.report
        while on_wire and on_wire[0][0] <= now:
            done, wire_bytes, tick = on_wire.popleft()
            report.tx_wire_bytes += wire_bytes
            if tick is not None:
                report.record_slack(tick, done, tick + period - done)
