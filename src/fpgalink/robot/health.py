"""The robot's health as statuses, sans-I/O: one per board (alive, enabled, what the link
counted, how much of the line it uses) and one for supervision (OK / WARN / ERROR and why).
The levels are ROS's ``diagnostic_msgs/DiagnosticStatus`` levels, so the ROS node and a
rosbag2 recording carry them as they are; nothing here knows ROS.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import IntEnum

from fpgalink.connection import LinkStats
from fpgalink.protocol import (
    BoardIdentity,
    IdentityMatch,
    compare_identity,
    declarations_digest,
    describe_identity,
)
from fpgalink.robot.supervision import State, StopReason, SupervisionEvent

__all__ = ["Level", "Status", "WireUse", "board_status", "supervision_status"]


class Level(IntEnum):
    OK = 0
    WARN = 1
    ERROR = 2  #: needs someone: a board not answering, the robot stopped because of it


@dataclass(frozen=True, slots=True)
class Status:
    name: str  #: ``board L``, ``supervision``
    hardware_id: str  #: the board's port, or ``robot``
    level: Level
    message: str
    values: tuple[tuple[str, str], ...] = ()


class WireUse:
    """Share of a line's capacity used between two reports, each direction (8N1: ten bit
    times per byte). The first report has nothing to compare with: ``None``."""

    def __init__(self, baud: int | None) -> None:
        self.baud = baud
        self._mark: tuple[float, int, int] | None = None

    def update(self, now: float, bytes_received: int,
               bytes_sent: int) -> tuple[float | None, float | None]:
        """(board → host, host → board) as fractions of the line since the last call."""
        mark, self._mark = self._mark, (now, bytes_received, bytes_sent)
        if mark is None or not self.baud or now <= mark[0]:
            return None, None
        capacity = self.baud / 10 * (now - mark[0])
        return (bytes_received - mark[1]) / capacity, (bytes_sent - mark[2]) / capacity


def _percent(share: float | None) -> str:
    return "" if share is None else f"{100 * share:.1f} %"


def board_status(board: str, hardware_id: str, *, alive: bool, enabled: bool,
                 stats: LinkStats, wire: tuple[float | None, float | None],
                 fault: str | None = None,
                 identity: tuple[BoardIdentity | None, bool] = (None, False)) -> Status:
    """ERROR when the board is not answering, or not ready (``fault``: restarted and being
    reconfigured, its telemetry stopped, restarted into another protocol declaration); WARN
    when messages were lost or damaged, or its firmware speaks another declaration than
    this host's (let through: ``allow_mismatch``). ``identity``: who it said it is, and
    whether it was asked (docs/protocol.md §8)."""
    board_identity, known = identity
    mismatch = known and compare_identity(board_identity) is IdentityMatch.MISMATCH
    if not alive:
        level, message = Level.ERROR, "not answering"
    elif fault is not None:
        level, message = Level.ERROR, fault
    elif mismatch:
        level, message = Level.WARN, ("alive; its firmware speaks another protocol "
                                      "declaration than this host's")
    elif stats.lost or stats.decode_errors:
        level, message = Level.WARN, "alive; messages lost or damaged"
    else:
        level, message = Level.OK, "alive"
    values = (
        ("alive", str(alive)), ("enabled", str(enabled)),
        ("telemetry received", str(stats.telemetry_received)),
        ("lost", str(stats.lost)), ("damaged", str(stats.decode_errors)),
        ("retries", str(stats.retries)), ("port losses", str(stats.port_losses)),
        ("restarts", str(stats.restarts)), ("watchdog lapses", str(stats.watchdog_lapses)),
        ("telemetry stalls", str(stats.telemetry_stalls)),
        ("bytes received", str(stats.bytes_received)), ("bytes sent", str(stats.bytes_sent)),
        ("wire use board to host", _percent(wire[0])),
        ("wire use host to board", _percent(wire[1])),
        ("identity", describe_identity(board_identity, known)),
        ("protocol", board_identity.digest if board_identity is not None else ""),
        ("host protocol", declarations_digest()),
    )
    return Status(f"board {board}", hardware_id or board, level, message, values)


#: Stops for a fault of the robot's own (not the caller's doing): ERROR.
_FAULTS = frozenset({StopReason.BOARD_LOST, StopReason.BOARD_RESTARTED,
                     StopReason.TELEMETRY_STALE, StopReason.WATCHDOG_LAPSED,
                     StopReason.TASK_FAILED})


def supervision_status(state: State, last_stop: SupervisionEvent | None,
                       blocked: Mapping[str, str] | None = None) -> Status:
    """ERROR when a fault stopped the robot (a board silent, restarted, its telemetry
    stopped, its watchdog lapsed; a robot task failed), WARN when the deadman lapsed, OK
    when enabled or disabled on request. ``blocked``: boards not ready, and why (enable is
    refused while any is)."""
    not_ready = "; ".join(f"{'the robot' if name == 'robot' else 'board ' + name}: {why}"
                          for name, why in (blocked or {}).items())
    if state is State.ENABLED:
        level, message = Level.OK, "enabled"
    elif last_stop is not None and last_stop.reason in _FAULTS:
        level, message = Level.ERROR, f"disabled: {last_stop.describe()}"
    elif last_stop is not None and last_stop.reason is StopReason.DEADMAN:
        level, message = Level.WARN, f"disabled: {last_stop.describe()}"
    else:
        level, message = Level.OK, "disabled"
    if not_ready and state is not State.ENABLED:
        level = Level.ERROR
        message += f" (not ready: {not_ready})"
    values = (("state", state.value),
              ("last stop", last_stop.describe() if last_stop is not None else ""),
              ("not ready", not_ready))
    return Status("supervision", "robot", level, message, values)
