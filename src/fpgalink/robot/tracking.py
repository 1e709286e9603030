"""Following the boards' telemetry, sans-I/O: each board's latest sample, odometry fed, the
wheels' encoder counts carried across a board's restarts (joint angles go on where the
counters start again), and each reader's stamped sample sets (:mod:`.stamping`)."""

from __future__ import annotations

from collections.abc import Callable, Mapping

from fpgalink.protocol import Telemetry
from fpgalink.protocol.params import CHANNEL_A
from fpgalink.protocol.robot import RobotDescription
from fpgalink.robot.drive import WheelCommand
from fpgalink.robot.joints import JointStates, joint_states
from fpgalink.robot.odometry import Odometry, OdometryState
from fpgalink.robot.stamping import SampleStamper, StampedSet

__all__ = ["Tracking"]

_WRAP_US, _HALF_US = 1 << 32, 1 << 31

#: a reader: its stamper, its sink (what the sink returns is not looked at) and its clock
Reader = tuple[SampleStamper, Callable[[StampedSet], object], Callable[[float], int]]


class Tracking:
    def __init__(self, description: RobotDescription, odometry: Odometry) -> None:
        self.description = description
        self.odometry = odometry
        #: each board's latest telemetry sample
        self.latest: dict[str, Telemetry] = {}
        #: encoder counts each wheel had before its board's restarts, and a restarted
        #: board's last sample before it (its counts carried at its next)
        self.count_offset: dict[tuple[str, int], int] = {}
        self._before_restart: dict[str, Telemetry] = {}
        self._readers: list[Reader] = []
        #: encoder pulses per turn and TorqueCoef (N·m/A) per (board, channel), as read
        #: from the boards at start and followed through every confirmed change
        self.resolution: dict[tuple[str, int], int] = {}
        self.torque_coef: dict[tuple[str, int], float] = {}

    def read_back(self, board: str, channel: int, param: str, value: float) -> None:
        """A wheel's resolution or torque coefficient as its board has it: odometry and
        joint states follow (``ValueError`` for a resolution odometry cannot use)."""
        if param == "IncSenzRes":
            self.odometry.set_resolution(board, channel, int(value))
            self.resolution[(board, channel)] = int(value)
        elif param == "TorqueCoef":
            self.torque_coef[(board, channel)] = float(value)

    def add(self, name: str, received: float, sample: Telemetry) -> None:
        """Board ``name``'s ``sample``, which arrived at ``received`` (the loop's clock)."""
        previous = self.latest.get(name) or self._before_restart.pop(name, None)
        if previous is not None and (sample.t_us - previous.t_us) % _WRAP_US >= _HALF_US:
            # Its clock went back: it restarted, and its counters start from 0 again (the
            # samples say so exactly where, however late its link's event is read).
            for wheel in self.description.wheels:
                if wheel.board == name:
                    key = (name, wheel.channel)
                    data = previous.a if wheel.channel == CHANNEL_A else previous.b
                    self.count_offset[key] = self.count_offset.get(key, 0) + data.position
        self.latest[name] = sample
        self.odometry.update(name, sample)

    def publish(self, name: str, received: float, sample: Telemetry) -> None:
        """Hand each reader its set, when this sample completes one."""
        for stamper, sink, clock in self._readers:
            stamped = stamper.add(name, sample, received, clock, self._odometry_now)
            if stamped is not None:
                sink(stamped)

    def _odometry_now(self) -> OdometryState:
        return self.odometry.state

    def drove(self, t_us: int, command: WheelCommand) -> None:
        """A ramp drove ``command`` at the first board's sample time ``t_us``."""
        for stamper, _, _ in self._readers:
            stamper.drove(t_us, command)

    def restarted(self, name: str) -> None:
        """Board ``name`` restarted: its counts and clock start again (not motion)."""
        latest = self.latest.pop(name, None)
        if latest is not None:
            self._before_restart[name] = latest
        self.odometry.restart(name)
        for stamper, _, _ in self._readers:
            stamper.restart(name)

    def add_reader(self, stamper: SampleStamper, clock: Callable[[float], int],
                   sink: Callable[[StampedSet], object]) -> None:
        self._readers.append((stamper, sink, clock))

    def remove_reader(self, sink: Callable[[StampedSet], object]) -> None:
        self._readers[:] = [reader for reader in self._readers if reader[1] != sink]

    def joint_states(self, samples: Mapping[str, Telemetry] | None = None
                     ) -> JointStates | None:
        """The four wheels from each board's latest sample, or from ``samples``."""
        return joint_states(self.description, self.latest if samples is None else samples,
                            {key: 10 * pulses for key, pulses in self.resolution.items()},
                            self.torque_coef, self.count_offset)
