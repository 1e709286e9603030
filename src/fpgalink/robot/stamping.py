"""Sample stamping, sans-I/O: the boards' telemetry joined into sets of one sample per board
(:class:`~fpgalink.robot.joints.SampleSets`), each sample's board time (``t_us``) mapped
onto a consumer's clock (:class:`~fpgalink.boardclock.BoardClock`: the host's epoch for a
recording, ROS time for the node), with the odometry the set completed and its stamp.
Done once here for the ROS node (``joint_states``, ``odom``, ``cmd_vel_out``) and the CLI's
recordings (``--rosbag2``).

A board that restarts starts its mapping again (:meth:`SampleStamper.restart`; its clock
going back does too). A clock that reads 0 has not started (ROS time under
``use_sim_time`` before the first ``/clock``): a set then is given unstamped
(:attr:`StampedSet.clocked` false), its samples mapped on nothing.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from fpgalink.boardclock import BoardClock
from fpgalink.protocol import Telemetry
from fpgalink.robot.drive import WheelCommand
from fpgalink.robot.joints import SampleSets
from fpgalink.robot.odometry import OdometryState

__all__ = ["SampleStamper", "StampedSet"]

_WRAP_US = 1 << 32


@dataclass(frozen=True, slots=True)
class StampedSet:
    """One sample per board, with when each was taken on the consumer's clock."""

    samples: Mapping[str, Telemetry]  #: board → its sample
    stamps: Mapping[str, int]  #: board → the sample's time, ns on the consumer's clock
    stamp: int  #: the first board's: the set's stamp (``joint_states``)
    received: int  #: ns on the consumer's clock when the set completed
    #: the robot's odometry as it stood when the set completed, and its stamp: the earliest
    #: of the boards' samples it integrated, never earlier than the stamp before
    odometry: OdometryState
    odometry_stamp: int
    #: body commands a ramp drove since the set before, each stamped at its control step
    driven: tuple[tuple[int, WheelCommand], ...] = ()

    @property
    def clocked(self) -> bool:
        """Whether its samples are stamped (the reader's clock had a time)."""
        return bool(self.stamps)


class SampleStamper:
    """Feed it every board's samples in arrival order (:meth:`add`); it gives a
    :class:`StampedSet` as soon as each board has a sample not yet used, never more often
    than ``min_period`` s of arrival time."""

    def __init__(self, boards: tuple[str, ...], min_period: float = 0.0) -> None:
        self.boards = boards
        self._sets = SampleSets(boards, min_period)
        self._clocks = {board: BoardClock() for board in boards}
        self._last_odometry = 0
        #: what a ramp drove since the last set: (the sample's t_us, the command, its stamp)
        self._driven: list[tuple[int, WheelCommand, int | None]] = []
        self._stamps: dict[str, int] = {}  #: each board's latest sample's stamp
        self.unclocked = 0  #: sets given unstamped: the consumer's clock read 0

    @property
    def min_period(self) -> float:
        return self._sets.min_period

    @min_period.setter
    def min_period(self, seconds: float) -> None:
        self._sets.min_period = seconds

    def restart(self, board: str) -> None:
        """``board`` restarted: its clock's mapping starts again (the drift kept)."""
        self._clocks[board].restart()

    def drove(self, t_us: int, command: WheelCommand) -> None:
        """A ramp drove ``command`` at the first board's sample ``t_us`` (added next): given
        with the next set, stamped as that sample is."""
        self._driven.append((t_us, command, None))

    def add(self, board: str, sample: Telemetry, received: float,
            clock: Callable[[float], int], odometry: Callable[[], OdometryState]
            ) -> StampedSet | None:
        """``board``'s ``sample``, which arrived at ``received`` (s, on the robot's loop's
        clock) and at ``clock(received)`` on the consumer's (ns): each board's clock maps
        its samples by their own arrival. A complete set carries ``odometry()``, the
        robot's then."""
        now_ns = clock(received)
        if now_ns:
            self._stamps[board] = stamp = self._clocks[board].ns(sample.t_us, now_ns)
            if board == self.boards[0]:
                # Each step at its own sample's stamp: as far from the next as the board
                # clock's mapping keeps consecutive samples, not a set's apart.
                self._driven = [(t_us, command, stamp if t_us == sample.t_us else at)
                                for t_us, command, at in self._driven]
        else:  # no time yet: mapped on nothing (a board clock anchored at 0 would be lost)
            self._stamps.pop(board, None)
        complete = self._sets.add(board, sample, received)
        if complete is None:
            return None
        if len(self._stamps) < len(self.boards):
            self.unclocked += 1
            return StampedSet(complete, {}, 0, now_ns, odometry(), 0)
        stamps = dict(self._stamps)  # each board's latest sample: the set's
        first = self.boards[0]
        stamp = stamps[first]
        odometry_stamp = max(min(stamps.values()), self._last_odometry + 1000)
        self._last_odometry = odometry_stamp
        driven, self._driven = self._driven, []
        t_first = complete[first].t_us
        return StampedSet(complete, stamps, stamp, now_ns, odometry(), odometry_stamp,
                          tuple((_before(stamp, t_first, t_us) if at is None else at, command)
                                for t_us, command, at in driven))


def _before(stamp: int, t_us: int, earlier_us: int) -> int:
    """The stamp of board time ``earlier_us``, given ``t_us``'s; a step more than a
    second apart (a restart between them) takes the stamp itself."""
    apart = (t_us - earlier_us) % _WRAP_US
    return stamp - apart * 1000 if apart < 1_000_000 else stamp
