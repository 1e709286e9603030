"""Health statuses: the levels ROS's diagnostics use, with the reason, and wire use as a
share of the line between two reports."""

from __future__ import annotations

import pytest

from fpgalink.connection import LinkStats
from fpgalink.robot.health import Level, WireUse, board_status, supervision_status
from fpgalink.robot.supervision import State, StopReason, SupervisionEvent


def test_wire_use_is_the_share_of_the_line_between_reports() -> None:
    wire = WireUse(1_000_000)  # 100,000 bytes a second each way
    assert wire.update(10.0, 0, 0) == (None, None)
    assert wire.update(10.5, 27_000, 5_000) == pytest.approx((0.54, 0.10))
    assert wire.update(10.5, 30_000, 5_000) == (None, None)  # no time passed: no figure
    assert WireUse(None).update(1.0, 0, 0) == (None, None)


@pytest.mark.parametrize(("alive", "stats", "level", "message"), [
    (True, LinkStats(), Level.OK, "alive"),
    (True, LinkStats(lost=3), Level.WARN, "alive; messages lost or damaged"),
    (True, LinkStats(malformed=1), Level.WARN, "alive; messages lost or damaged"),
    (False, LinkStats(), Level.ERROR, "not answering"),
])
def test_a_board_is_ok_warn_or_error(alive: bool, stats: LinkStats, level: Level,
                                     message: str) -> None:
    status = board_status("L", "/dev/ttyUSB0", alive=alive, enabled=False, stats=stats,
                          wire=(0.5, 0.25))
    assert (status.name, status.hardware_id) == ("board L", "/dev/ttyUSB0")
    assert (status.level, status.message) == (level, message)
    values = dict(status.values)
    assert values["alive"] == str(alive) and values["lost"] == str(stats.lost)
    assert values["wire use board to host"] == "50.0 %"


def test_supervision_is_error_only_when_a_board_stopped_the_robot() -> None:
    lost = SupervisionEvent(1.0, State.DISABLED, StopReason.BOARD_LOST, "R", "board lost")
    lapsed = SupervisionEvent(1.0, State.DISABLED, StopReason.DEADMAN)
    asked = SupervisionEvent(1.0, State.DISABLED, StopReason.REQUESTED)
    assert supervision_status(State.ENABLED, None).level is Level.OK
    error = supervision_status(State.DISABLED, lost)
    assert error.level is Level.ERROR and "board R" in error.message
    assert supervision_status(State.DISABLED, lapsed).level is Level.WARN
    assert supervision_status(State.DISABLED, asked).level is Level.OK
    assert supervision_status(State.DISABLED, None).message == "disabled"
