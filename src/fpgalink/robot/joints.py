"""The wheels as joints (the seed's URDF: continuous joints ``FL``, ``BL``, ``FR``, ``BR``
about their y axes), from the boards' telemetry, sans-I/O: what a ROS ``JointState`` or a
bag carries. Angles and speeds are forward-positive (a positive rotation about a wheel's y
axis rolls the robot forward), whatever each board's own sign.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from fpgalink.protocol import ChannelTelemetry, Telemetry
from fpgalink.protocol.params import CHANNEL_A
from fpgalink.protocol.robot import WHEEL_NAMES, RobotDescription

__all__ = ["JointStates", "SampleSets", "joint_states", "wheel_channel"]


@dataclass(frozen=True, slots=True)
class JointStates:
    names: tuple[str, ...]
    position: tuple[float, ...]  #: rad, from the encoder counts
    velocity: tuple[float, ...]  #: rad/s, the boards' measured speeds
    effort: tuple[float, ...]  #: N·m, measured current × TorqueCoef


class SampleSets:
    """The boards' telemetry joined into sets of one sample per board, each sample in one
    set at most, at most one set per ``min_period`` seconds: a set is complete as soon as
    every board has a sample not yet used (the newest one of each), so a set goes out with
    the sample that completes it. ``slack`` absorbs arrival jitter at the full rate."""

    def __init__(self, boards: tuple[str, ...], min_period: float = 0.0,
                 slack: float = 0.0005) -> None:
        self.boards = frozenset(boards)
        self.min_period = min_period
        self.slack = slack
        self.latest: dict[str, Telemetry] = {}
        self._fresh: set[str] = set()
        self._last_set = -math.inf

    def add(self, board: str, sample: Telemetry, now: float) -> dict[str, Telemetry] | None:
        """Take ``board``'s ``sample`` at ``now`` (s); the complete set, or ``None``."""
        self.latest[board] = sample
        self._fresh.add(board)
        if self._fresh >= self.boards and now - self._last_set >= self.min_period - self.slack:
            self._last_set = now
            self._fresh.clear()
            return dict(self.latest)
        return None


def wheel_channel(sample: Telemetry, channel: int) -> ChannelTelemetry:
    return sample.a if channel == CHANNEL_A else sample.b


def joint_states(description: RobotDescription, latest: Mapping[str, Telemetry],
                 counts_per_turn: Mapping[tuple[str, int], int],
                 torque_coef: Mapping[tuple[str, int], float],
                 count_offset: Mapping[tuple[str, int], int] | None = None
                 ) -> JointStates | None:
    """The four wheels from each board's latest sample (``None`` until every board has
    sent one). ``counts_per_turn`` and ``torque_coef`` by (board, channel), as read from
    the boards; ``count_offset``: counts a wheel had before its board restarted (its
    counter starts from 0 again; the joint's angle goes on). A non-finite speed or
    current is reported as NaN (JointState allows it)."""
    offsets = count_offset or {}
    if any(board not in latest for board in description.boards):
        return None
    position, velocity, effort = [], [], []
    for name in WHEEL_NAMES:
        wheel = description.wheel(name)
        data = wheel_channel(latest[wheel.board], wheel.channel)
        key = (wheel.board, wheel.channel)
        per_turn = counts_per_turn.get(key, 0)
        counts = data.position + offsets.get(key, 0)
        position.append(math.tau * counts / per_turn * wheel.forward if per_turn
                        else math.nan)
        velocity.append(math.radians(data.speed) * wheel.forward)
        effort.append(data.current * torque_coef.get(key, math.nan) * wheel.forward)
    return JointStates(WHEEL_NAMES, tuple(position), tuple(velocity), tuple(effort))
