"""Wheel odometry from encoder counts (the seed's WheelOdometry node), sans-I/O.

Pose comes from the wheels' encoder *positions* — the exact integral of their rotation —
never from integrating reported speeds, so it does not drift with sample timing or lost
telemetry: a lost ``TM``'s motion comes with the next sample, shared over the steps it
spans. Counts are i32 on the wire and
wrap; differences are taken modulo 2³². Each step moves the body along an arc through the
skid-steer model (:meth:`~fpgalink.protocol.robot.SkidSteer.displacement`), and the pose
covariance grows by a standard odometry motion model (:class:`OdometryNoise`).

A step pairs the boards' samples by the stretch of board time they close, not by the order
they are handled in: each board's motion waits in a queue of its own, one entry per sample
with the whole milliseconds of its own clock since the one before (``TsTimerPeriod`` is
whole milliseconds, so rounding takes out the clocks' jitter and a crystal's drift, which
would add up), and a step takes the same milliseconds from every board's oldest entry, a
share of an entry that spans more. So reads in batches (ten of L's samples, then ten of
R's) step the body exactly as samples handled one at a time do, a host that handles two of
one board's samples before the other's pairs them as they were sent, and a lost sample
shifts no pairing after it. (The message counter is no measure of periods: a board's
replies take counter values too.) A board that falls silent leaves the others' motion
queued, at most :data:`QUEUED_SAMPLES` entries each (the oldest two then merge: memory
stays bounded, and no motion is lost), until it reports again (its next sample closes the
whole silence) or restarts. After a restart the boards pair again from the restarted
board's first sample as it is handled: with reads in batches, the other board's samples of
that batch may then pair up to a batch apart, as every sample did before this pairing.

The running totals (distance travelled, angle turned) and the covariance's growth are
driven by the motion the encoders resolve, not by each step's jitter: a step pairs the
two boards' samples of the same period, taken up to a period apart (their timers are not
in phase), and counts come in whole counts, so
a straight line's steps alternate small turns left and right (and a turn in place small
steps forward and back) that cancel in the pose but would add up in absolute totals. The
totals follow the cumulative distance and heading through a play (backlash) operator whose
band is that jitter's bound — one encoder count and a period of a side at full speed —
so jitter moves nothing, and motion beyond it counts in full (less the band once per
reversal).

A board that restarts counts from 0 again (:meth:`restart`, or its clock ``t_us`` going
back, whichever comes first): its next sample is a new reference, and motion the encoders
did not see while it was away is not invented.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Final

from fpgalink.protocol import Telemetry
from fpgalink.protocol.params import CHANNEL_A, CHANNEL_B
from fpgalink.protocol.robot import (
    LEFT_WHEELS,
    RIGHT_WHEELS,
    Pose,
    RobotDescription,
    SkidSteer,
    integrate_arc,
)

__all__ = ["QUEUED_SAMPLES", "Odometry", "OdometryState", "Play", "count_delta"]

#: The most samples of one board's motion queued for the other boards' (1 s at 1 kHz): a
#: board silent longer leaves the others' oldest two merged, none dropped.
QUEUED_SAMPLES: Final = 1000


class _Motion:
    """One board's motion over ``ms`` whole milliseconds of its clock: metres by wheel."""

    __slots__ = ("metres", "ms")

    def __init__(self, ms: int, metres: dict[str, float]) -> None:
        self.ms = ms
        self.metres = metres

_WRAP = 1 << 32
_HALF = 1 << 31

Matrix = list[list[float]]


def count_delta(new: int, old: int) -> int:
    """``new − old`` for i32 encoder counts, across the wrap at ±2³¹."""
    return (new - old + _HALF) % _WRAP - _HALF


class Play:
    """The play (backlash) operator: an output that follows its input only once the input
    leaves a band of ±``band`` around it. ``update(x)`` returns how far the output moved."""

    __slots__ = ("band", "output")

    def __init__(self, band: float) -> None:
        self.band = band
        self.output = 0.0

    def update(self, value: float) -> float:
        output, band = self.output, self.band
        if value > output + band:
            self.output = value - band
        elif value < output - band:
            self.output = value + band
        else:
            return 0.0
        return self.output - output


@dataclass(frozen=True, slots=True)
class OdometryState:
    """What :class:`Odometry` knows at one moment."""

    pose: Pose
    v: float  #: m/s, body speed (from the wheels' measured speeds)
    omega: float  #: rad/s
    covariance: tuple[tuple[float, ...], ...]  #: 3×3 over (x, y, θ)
    distance: float  #: m travelled (path length)
    turned: float  #: rad turned (absolute)

    #: What a 6×6 (x, y, z, roll, pitch, yaw) covariance says of what planar odometry does
    #: not estimate: a large variance, as REP-145 asks, not a zero that claims certainty.
    UNESTIMATED_VARIANCE = 1e6

    def covariance_6x6(self) -> list[float]:
        """The pose covariance row-major over (x, y, z, roll, pitch, yaw), as ROS's
        ``PoseWithCovariance`` carries it."""
        out = [0.0] * 36
        index = (0, 1, 5)  # x, y, θ → x, y, yaw
        for i, row in enumerate(index):
            for j, col in enumerate(index):
                out[row * 6 + col] = self.covariance[i][j]
        for unestimated in (2, 3, 4):
            out[unestimated * 7] = self.UNESTIMATED_VARIANCE
        return out


class Odometry:
    """Feed it each board's telemetry (:meth:`update`); read :attr:`pose`, :attr:`state`.
    The body moves one step for each stretch of board time every board has reported (once
    a period at 1 kHz telemetry); a lost sample's motion comes with the next, shared.

    The encoder resolution of every wheel must be given first (:meth:`set_resolution`,
    from the boards' ``IncSenzRes``): it is read from the boards, never assumed."""

    def __init__(self, description: RobotDescription, kinematics: SkidSteer | None = None,
                 pose: Pose | None = None) -> None:
        self.description = description
        self.kinematics = kinematics or description.kinematics()
        self.pose = pose or Pose()
        self.covariance: Matrix = [[0.0] * 3 for _ in range(3)]
        self.v = 0.0
        self.omega = 0.0
        self._travelled = 0.0  #: m, what the play operator let through
        self._rotated = 0.0  #: rad, likewise
        self.steps = 0
        self._wheels = {(w.board, w.channel): w for w in description.wheels}
        self._counts_per_turn: dict[str, int] = {}
        self._last_counts: dict[str, int] = {}
        self._unintegrated: dict[str, float] = {w.name: 0.0 for w in description.wheels}
        self._speeds: dict[str, float] = {w.name: 0.0 for w in description.wheels}
        #: the boards with wheels: a step waits for each of them
        self._boards = tuple(b for b in description.boards
                             if any(w.board == b for w in description.wheels))
        #: each board's motion not yet stepped, one entry per sample
        self._queued: dict[str, deque[_Motion]] = {b: deque() for b in self._boards}
        self._queues = tuple(self._queued.values())  #: the same, in a step's order
        self._path = 0.0  #: m, the cumulative signed distance along the path
        self._heading = 0.0  #: rad, the cumulative (unwrapped) turn
        self._play_path = Play(0.0)
        self._play_heading = Play(0.0)
        self._period = 0.001  #: s, between a board's samples (as their t_us say)
        self._last_t_us: dict[str, int] = {}
        #: boards that restarted: their next sample is a new reference for every wheel
        self._reanchor: set[str] = set()
        self.reanchors = 0  #: boards re-anchored after a restart

    def set_resolution(self, board: str, channel: int, pulses_per_turn: int) -> None:
        """The wheel on ``board``/``channel`` has ``pulses_per_turn`` encoder pulses a turn
        (the board counts 10 per pulse, SPEC §5)."""
        wheel = self._wheels.get((board, channel))
        if wheel is None:
            raise ValueError(f"no wheel on board {board!r} channel {channel}")
        if pulses_per_turn <= 0:
            raise ValueError(f"{wheel.name}: the board reports {pulses_per_turn} encoder "
                             "pulses per turn; odometry needs a positive resolution")
        self._counts_per_turn[wheel.name] = 10 * pulses_per_turn
        self._set_bands()

    def _set_bands(self) -> None:
        """The jitter bound of one step's sides: a count of the coarsest wheel, and a side
        at full speed over one period (the boards' samples pair up to a period apart)."""
        if not self._counts_per_turn:
            return
        radius = self.description.wheel_radius
        count = max(math.tau * radius / n for n in self._counts_per_turn.values())
        side = count + math.radians(self.description.max_wheel_speed) * radius * self._period
        self._play_path.band = side
        self._play_heading.band = 2 * side / self.kinematics.effective_track

    def set_kinematics(self, description: RobotDescription, kinematics: SkidSteer) -> None:
        """Another wheel radius, track or χ from now on (the pose so far stays)."""
        self.description, self.kinematics = description, kinematics
        self._set_bands()

    @property
    def ready(self) -> bool:
        return len(self._counts_per_turn) == len(self._wheels)

    def reset(self, pose: Pose | None = None) -> None:
        """Start again from ``pose`` with zero covariance (counts keep their reference)."""
        self.pose = pose or Pose()
        self.covariance = [[0.0] * 3 for _ in range(3)]
        self._travelled = self._rotated = 0.0
        self._path = self._heading = 0.0
        self._play_path.output = self._play_heading.output = 0.0

    def restart(self, board: str) -> None:
        """``board`` restarted: its counters start from 0 again, and what its wheels did
        meanwhile was not measured. Its next sample is a new reference; what the other
        boards measured since the last step is dropped with it (one side's motion alone
        would read as a turn), so the pose neither jumps nor invents a turn."""
        self._reanchor.add(board)
        self._last_t_us.pop(board, None)
        for wheel in self.description.wheels:
            if wheel.board == board:
                self._last_counts.pop(wheel.name, None)
                self._speeds[wheel.name] = 0.0
        self._drop_unintegrated()

    def _drop_unintegrated(self) -> None:
        for name in self._unintegrated:
            self._unintegrated[name] = 0.0
        for queue in self._queues:
            queue.clear()

    def update(self, board: str, sample: Telemetry) -> None:
        """One ``TM`` of ``board``: its wheels' positions and speeds."""
        last_t_us = self._last_t_us.get(board)
        if last_t_us is not None and (sample.t_us - last_t_us) % _WRAP >= _HALF:
            # Its clock went back (a wrap goes forward): it restarted, whether or not its
            # link has said so yet, and its counters start from 0 again.
            self.restart(board)
            last_t_us = None
        self._last_t_us[board] = sample.t_us
        ms = 1  # the first sample is a reference: it closes nothing
        if last_t_us is not None:
            apart_us = (sample.t_us - last_t_us) % _WRAP
            ms = round(apart_us / 1000)
            apart = apart_us / 1e6
            if 0 < apart <= 1.0 and apart != self._period:
                self._period = apart
                self._set_bands()
        reference = board in self._reanchor
        if reference:
            self._reanchor.discard(board)
            self.reanchors += 1
            self._drop_unintegrated()
        moved: dict[str, float] = {}
        for channel, data in ((CHANNEL_A, sample.a), (CHANNEL_B, sample.b)):
            wheel = self._wheels.get((board, channel))
            if wheel is None:
                continue
            per_turn = self._counts_per_turn.get(wheel.name)
            if per_turn is None:
                raise ValueError(f"{wheel.name}: encoder resolution not known yet "
                                 "(set_resolution from the board's IncSenzRes)")
            last = self._last_counts.get(wheel.name)
            self._last_counts[wheel.name] = data.position
            if math.isfinite(data.speed):
                self._speeds[wheel.name] = data.speed * wheel.forward
            if last is None:
                continue  # the first sample only sets the reference
            turns = count_delta(data.position, last) / per_turn
            moved[wheel.name] = (
                turns * math.tau * self.kinematics.side_radius(wheel.left) * wheel.forward)
        # A reference moves nothing: the others pair with what follows. A step moves every
        # side together (one board at a time would zig-zag the heading, and a turn in place
        # would add path length), each board's motion of the same period.
        if moved:
            self._queue(board, moved, ms)
            self._step_paired()
        self._update_twist()

    def _queue(self, board: str, moved: dict[str, float], ms: int) -> None:
        queue = self._queued[board]
        if ms <= 0:
            # The same stretch again (a repeated sample): its motion, if any, goes with the
            # last (or the next step, the last already taken); it is no new stretch, which
            # would shift every later pairing.
            into = queue[-1].metres if queue else self._unintegrated
            for name, metres in moved.items():
                into[name] = into.get(name, 0.0) + metres
            return
        queue.append(_Motion(ms, moved))
        if len(queue) > QUEUED_SAMPLES:
            oldest = queue.popleft()
            merged = queue[0]
            merged.ms += oldest.ms
            for name, metres in oldest.metres.items():
                merged.metres[name] = merged.metres.get(name, 0.0) + metres

    def _step_paired(self) -> None:
        """A step for each stretch of board time every board has queued motion for."""
        queues = self._queues
        unintegrated = self._unintegrated
        while all(queues):
            ms = min(queue[0].ms for queue in queues)
            for queue in queues:
                head = queue[0]
                if head.ms == ms:
                    queue.popleft()
                    for name, metres in head.metres.items():
                        unintegrated[name] += metres
                    continue
                # The step takes its share of an entry spanning more (a lost sample's
                # successor, a silence, merged entries): the rest stays for the next.
                share = ms / head.ms
                for name, metres in head.metres.items():
                    part = metres * share
                    unintegrated[name] += part
                    head.metres[name] = metres - part
                head.ms -= ms
            self._integrate()

    def _integrate(self) -> None:
        left, right = LEFT_WHEELS, RIGHT_WHEELS
        left_m = sum(self._unintegrated[n] for n in left) / len(left)
        right_m = sum(self._unintegrated[n] for n in right) / len(right)
        for name in self._unintegrated:
            self._unintegrated[name] = 0.0
        if left_m == 0.0 and right_m == 0.0:
            return
        distance, turn = self.kinematics.displacement(left_m, right_m)
        self._path += distance
        self._heading += turn
        moved = self._play_path.update(self._path)
        turned = self._play_heading.update(self._heading)
        if moved or turned:
            # Before the pose moves: the motion model's Jacobians at the step's start.
            self._propagate(moved, turned)
            self._travelled += abs(moved)
            self._rotated += abs(turned)
        self.pose = integrate_arc(self.pose, distance, turn)
        self.steps += 1

    def _propagate(self, distance: float, turn: float) -> None:
        """P ← G P Gᵀ + V M Vᵀ for a step (distance, turn) from the current pose."""
        mid = self.pose.theta + turn / 2.0
        c, s = math.cos(mid), math.sin(mid)
        g = [[1.0, 0.0, -distance * s], [0.0, 1.0, distance * c], [0.0, 0.0, 1.0]]
        v = [[c, -distance * s / 2.0], [s, distance * c / 2.0], [0.0, 1.0]]
        noise = self.description.odometry
        m = (noise.distance_noise * abs(distance),
             noise.turn_noise * abs(turn) + noise.drift_noise * abs(distance))
        p = self.covariance
        gp = [[sum(g[i][k] * p[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
        self.covariance = [
            [sum(gp[i][k] * g[j][k] for k in range(3))
             + v[i][0] * m[0] * v[j][0] + v[i][1] * m[1] * v[j][1] for j in range(3)]
            for i in range(3)
        ]

    def _update_twist(self) -> None:
        speeds = self._speeds
        left = (speeds["FL"] + speeds["BL"]) / 2.0
        right = (speeds["FR"] + speeds["BR"]) / 2.0
        self.v, self.omega = self.kinematics.body_twist(left, right)

    @property
    def queued(self) -> dict[str, int]:
        """Samples of each board's motion waiting for the other boards' of the same time."""
        return {board: len(queue) for board, queue in self._queued.items()}

    @property
    def distance(self) -> float:
        """m travelled (path length): the motion let through, and what is within the band
        now (at most one band, never accumulating)."""
        return self._travelled + abs(self._path - self._play_path.output)

    @property
    def turned(self) -> float:
        """rad turned (absolute), as :attr:`distance`."""
        return self._rotated + abs(self._heading - self._play_heading.output)

    @property
    def state(self) -> OdometryState:
        return OdometryState(self.pose, self.v, self.omega,
                             tuple(tuple(row) for row in self.covariance),
                             self.distance, self.turned)
