"""An emulated robot and the host's sans-I/O robot parts on one emulated clock: a
``Connection`` per board, :class:`~fpgalink.robot.odometry.Odometry`, wheel commands and the
go-to controller, stepped 1 ms at a time. No wall clock: a 1 m square runs in about a
second, the same way on a busy machine as on an idle one."""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass, field

from fpgaemu.firmware import Firmware
from fpgaemu.robot import EmulatedRobot
from fpgaemu.timeline import ms
from fpgalink import Connection, Telemetry
from fpgalink.protocol import References, lookup
from fpgalink.protocol.params import CHANNEL_A
from fpgalink.protocol.robot import Pose, RobotDescription, seed_robot
from fpgalink.robot.drive import wheel_command
from fpgalink.robot.goto import GoTo, GoToSettings
from fpgalink.robot.odometry import Odometry

STEP_MS = 1
CONTROL_EVERY_MS = 10  #: RV every 10 ms, as the robot issue's scenario


@dataclass
class RobotSim:
    robot: EmulatedRobot
    description: RobotDescription
    odometry: Odometry
    conns: dict[str, Connection] = field(default_factory=dict)
    now_ms: int = 0
    command: tuple[float, float] = (0.0, 0.0)
    #: (left, right) wheel references, deg/s, sent instead of the body command when set
    wheels: tuple[float, float] | None = None
    #: per-board hooks called with each telemetry sample
    on_telemetry: list[Callable[[str, Telemetry], None]] = field(default_factory=list)
    #: the host receives board R's samples one step late at random (seeded), as two ports
    #: read in turn do: odometry then pairs samples up to a period apart
    arrival_jitter: random.Random | None = None
    _held: list[Telemetry] = field(default_factory=list)

    @classmethod
    def make(cls, surface: str = "ideal", description: RobotDescription | None = None,
             odometry_surface: str | None = None, faults: dict[str, list[str]] | None = None,
             pose: Pose | None = None, body: str = "kinematic", seed: int = 0,
             arrival_jitter_seed: int | None = None) -> RobotSim:
        description = description or seed_robot()
        if surface in description.surfaces:
            description = description.on_surface(surface)
        robot = EmulatedRobot(description, surface, faults=faults, body=body, seed=seed)
        if pose is not None:
            if robot.physics is not None:
                robot.physics.place(pose)
            else:
                robot.body.pose = pose
        odometry = Odometry(description, description.kinematics(odometry_surface), pose)
        sim = cls(robot, description, odometry)
        if arrival_jitter_seed is not None:
            sim.arrival_jitter = random.Random(arrival_jitter_seed)
        for name in robot.boards:
            conn = Connection()
            conn.start(0.0)
            sim.conns[name] = conn
        sim._configure()
        return sim

    @property
    def now(self) -> float:
        return self.now_ms / 1000.0

    def _configure(self) -> None:
        """Telemetry on, enabled; resolution as the boards report it (their defaults)."""
        streaming = lookup("GetDataPeriodical")
        for name, conn in self.conns.items():
            conn.set_param(streaming, 0, 1, self.now)
            conn.enable(self.now)
            firmware = self.robot.boards[name].peripherals["firmware"]
            assert isinstance(firmware, Firmware)
            for wheel in self.description.wheels:
                if wheel.board == name:
                    pulses = firmware.value("IncSenzRes", wheel.channel)
                    self.odometry.set_resolution(name, wheel.channel, int(pulses))
        self.run(0.05)

    def drive(self, v: float, omega: float) -> None:
        self.command = (v, omega)

    def hold_wheels(self, left_dps: float, right_dps: float) -> None:
        """Both left wheels at ``left_dps``, both right at ``right_dps`` (the seed's §3.6
        experiments were run this way)."""
        self.wheels = (left_dps, right_dps)

    def _send_command(self) -> None:
        if self.wheels is not None:
            references: dict[str, list[float]] = {b: [0.0, 0.0] for b in self.conns}
            for wheel in self.description.wheels:
                side = self.wheels[0] if wheel.left else self.wheels[1]
                references[wheel.board][wheel.channel - 1] = side * wheel.forward
            for board, (ref_a, ref_b) in references.items():
                self.conns[board].send(References(ref_a, ref_b), self.now)
            return
        command = wheel_command(self.description, *self.command)
        for board, (ref_a, ref_b) in command.references.items():
            self.conns[board].send(References(ref_a, ref_b), self.now)

    def run(self, seconds: float, control: Callable[[RobotSim], None] | None = None) -> None:
        """Advance ``seconds``; ``control(sim)`` every control period (before the RV)."""
        for _ in range(round(seconds * 1000 / STEP_MS)):
            if self.now_ms % CONTROL_EVERY_MS == 0:
                if control is not None:
                    control(self)
                self._send_command()
            for name, conn in self.conns.items():
                conn.handle_timer(self.now)
                data = conn.data_to_send()
                if data:
                    self.robot.boards[name].host_write(data)
            self.now_ms += STEP_MS
            self.robot.run_until(ms(self.now_ms))
            for name, conn in self.conns.items():
                conn.receive_data(self.robot.boards[name].read_host_bytes(), self.now)
                samples = [e for e in conn.events() if isinstance(e, Telemetry)]
                if self.arrival_jitter is not None and name == "R":
                    samples, self._held = self._held + samples, []
                    if samples and self.arrival_jitter.random() < 0.5:
                        self._held = [samples.pop()]
                for event in samples:
                    self.odometry.update(name, event)
                    for hook in self.on_telemetry:
                        hook(name, event)

    def go_to(self, x: float, y: float, theta: float | None = None,
              settings: GoToSettings | None = None, limit_s: float = 60.0) -> GoTo:
        """Run the position controller until it arrives and the robot rests, or the limit."""
        controller = GoTo(x, y, theta, settings or GoToSettings(
            max_speed=self.description.max_linear_speed,
            max_turn_rate=self.description.max_angular_speed_rad))

        def control(sim: RobotSim) -> None:
            step = controller.step(sim.odometry.pose, sim.now)
            sim.drive(step.v, step.omega)

        end = self.now + limit_s
        while self.now < end and not controller.done:
            self.run(0.01, control)
        self.drive(0.0, 0.0)
        self.run(1.0)  # come to rest
        return controller

    @property
    def truth(self) -> Pose:
        return self.robot.truth().pose

    def wheel_speeds(self) -> dict[str, float]:
        """Each wheel's measured speed (deg/s, board sign) from the latest telemetry."""
        out = {}
        for wheel in self.description.wheels:
            latest = self.conns[wheel.board].latest_telemetry
            assert latest is not None
            out[wheel.name] = (latest.a if wheel.channel == CHANNEL_A else latest.b).speed
        return out

