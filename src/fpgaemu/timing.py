"""The board's own timing report (SPEC §7): how its output fitted its timer periods.

The firmware records, for every period, whether its ``TM`` left the wire before the next
tick and with how much slack; :meth:`TimingReport.summary` adds the line utilisation per
direction. Slack is kept as a histogram of exact values (a handful of distinct values in
practice) and missed periods as a bounded list, so memory stays flat however long the
board runs.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final

if TYPE_CHECKING:
    from fpgaemu.board import Board

__all__ = ["MISSED_LISTED", "TimingReport"]

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
