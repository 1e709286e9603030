"""The emulated-clock harness: boards and the host's sans-I/O side on one integer-cycle
timeline. Nothing sleeps and nothing reads a wall clock, so 60 s of 1 kHz telemetry or a
1 m square driven by the go-to controller runs in seconds, the same on a busy machine as on
an idle one.

:class:`Cable` is one board's cable: the board and fpgalink's :class:`~fpgalink.Connection`
at the host's end, with the one pump step an asyncio ``Link`` does (:meth:`Cable.pump`):
feed the TX bytes that completed to the Connection, hand its events on, fire its timer when
due and put what it queued on the RX pin. A test drives it as the host itself
(:meth:`Cable.run`, :meth:`Cable.request`, ...) or lets the host's link loop run
(:meth:`Cable.serve`). :class:`RobotSim` is an emulated robot with a cable per board on the
robot's shared timeline, and the host's odometry, wheel commands and go-to controller.
"""

from __future__ import annotations

import math
import os
import random
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from fpgaemu.board import Board, ChannelIo
from fpgaemu.build import build_board
from fpgaemu.cfirmware import CFirmware
from fpgaemu.firmware import Firmware
from fpgaemu.motor import Motors, WheelPlant
from fpgaemu.robot import EmulatedRobot
from fpgaemu.timeline import CLOCK_HZ, ms, seconds_to_cycles
from fpgaemu.timer import Timer
from fpgalink import Connection, Telemetry
from fpgalink.events import BoardFound
from fpgalink.protocol import (
    Disable,
    Enable,
    Message,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    References,
    encode_message,
    lookup,
)
from fpgalink.protocol.params import CHANNEL_A
from fpgalink.protocol.robot import Pose, RobotDescription, seed_robot
from fpgalink.robot.drive import wheel_command
from fpgalink.robot.goto import GoTo, GoToSettings
from fpgalink.robot.odometry import Odometry

MS = ms(1)  #: cycles per millisecond
#: the host's heartbeat while a test keeps the board enabled: well inside its 300 ms watchdog
RE_EVERY_MS = 100
#: the firmware :meth:`Cable.make` builds boards with (tests/support/firmwares.py sets it)
DEFAULT_FIRMWARE = "python"

#: FPGALINK_LONG=1 runs every reliability guarantee at full scale (see docs/reliability.md).
LONG = os.environ.get("FPGALINK_LONG") == "1"
#: a TM every 1 ms tick
STREAMING = {"TsTimerPeriod": 1, "GetDataPeriodical": 1}


def scale(ci: int, full: int) -> int:
    return full if LONG else ci


EventSink = Callable[[Any], None]


def _ignore(event: object) -> None:
    pass


@dataclass
class Cable:
    """One board and the host's side of its link, on the board's timeline."""

    board: Board
    #: the test writes what it sends itself, the board's UART paces it: no pacing here
    conn: Connection = field(default_factory=lambda: Connection(baud=None))
    #: the host link loop's period (:meth:`step`, :meth:`serve`)
    step_s: float = 0.001
    #: the host's link loop fires the Connection's timer and writes what it queued after
    #: each step; off, the host is stalled or dead and only reads
    host_alive: bool = True
    #: send ``RE`` every RE_EVERY_MS while :meth:`run` advances time
    keep_enabled: bool = False
    #: what :meth:`run` and :meth:`drain` collected, by kind
    telemetry: list[Telemetry] = field(default_factory=list)
    replies: list[ParamAck | ParamNack] = field(default_factory=list)
    other: list[object] = field(default_factory=list)
    wire_bytes_read: int = 0
    #: keep :attr:`writes`
    record_writes: bool = False
    #: the cycle each host write's last stop bit ends, and the bytes
    writes: list[tuple[int, bytes]] = field(default_factory=list)
    #: TM content the firmware queued, by counter (recorded at the firmware's send call when
    #: built with ``record_tm``)
    sent_tm: dict[int, bytes] = field(default_factory=dict)
    _next_re: int = 0

    # --- building -------------------------------------------------------------------------

    @staticmethod
    def make(*, baud: int = 1_000_000, gear: str = "high",
             settings: dict[str, Any] | None = None,
             firmware_kind: str | None = None) -> Cable:
        """A board with the test as its host (:meth:`run`, :meth:`request`, ...)."""
        board = build_board(baud=baud, gear=gear, settings=settings,
                            firmware=firmware_kind or DEFAULT_FIRMWARE)
        return Cable(board)

    @staticmethod
    def linked(*, seed: int = 0, faults: list[str] | None = None,
               settings: dict[str, Any] | None = None, record_tm: bool = False,
               **conn_options: Any) -> Cable:
        """A board with a host whose link loop runs (:meth:`serve`), as an asyncio ``Link``
        does: a paced Connection made with ``conn_options``, its writes recorded."""
        board = build_board(seed=seed, settings=settings or {}, faults=faults or [])
        cable = Cable(board, Connection(**conn_options), record_writes=True)
        if record_tm:
            board.uartsend.on_frame(cable._sent_frame)
        return cable

    def _sent_frame(self, content: bytes, cycle: int) -> None:
        if content[:2] == b"TM":
            self.sent_tm[int(content[2:7])] = content

    # --- the board's parts ----------------------------------------------------------------

    @property
    def firmware(self) -> Firmware | CFirmware:
        """The board's software (a new one after a power cycle)."""
        firmware = self.board.peripherals["firmware"]
        assert isinstance(firmware, Firmware | CFirmware)
        return firmware

    def io(self, code: int) -> ChannelIo:
        """Channel ``code``'s PWM stage, encoder and current sensor."""
        return self.board.channels[code]

    def wheel(self, code: int) -> WheelPlant:
        """Channel ``code``'s motor and wheel (brought up to the last sample)."""
        motors = self.board.peripherals["motors"]
        assert isinstance(motors, Motors)
        return motors.wheels[code]

    @property
    def timer(self) -> Timer:
        return self.board.timer

    @property
    def now_s(self) -> float:
        return self.board.now / CLOCK_HZ

    # --- the cable: the pump's parts ------------------------------------------------------

    def write(self, data: bytes, cycle: int | None = None) -> int:
        """Put ``data`` on the RX pin (now, or at ``cycle``); returns its last STOP's cycle."""
        end = self.board.host_write(data, cycle)
        if self.record_writes and data:
            self.writes.append((end, data))
        return end

    def flush(self) -> None:
        """Put what the Connection queued on the RX pin."""
        data = self.conn.data_to_send()
        if data:
            self.write(data)

    def receive(self) -> list[object]:
        """Feed every TX byte the board finished sending by now to the Connection; its
        events."""
        data = self.board.read_host_bytes()
        self.wire_bytes_read += len(data)
        self.conn.receive_data(data, self.now_s)
        return list(self.conn.events())

    def fire_timer(self) -> list[object]:
        """Fire the Connection's timer if it is due; the events that made."""
        now = self.now_s
        deadline = self.conn.get_timer()
        if deadline is None or deadline > now:
            return []
        self.conn.handle_timer(now)
        return list(self.conn.events())

    def pump(self, on_event: EventSink | None = None) -> None:
        """The host link's step once the board ran: read, hand the events to ``on_event``
        and, while :attr:`host_alive`, fire the timer when due and write what it queued."""
        sink = on_event or _ignore
        for event in self.receive():
            sink(event)
        if not self.host_alive:
            return
        for event in self.fire_timer():
            sink(event)
        self.flush()

    def step(self, on_event: EventSink | None = None) -> None:
        """One period of the host's link loop: the board runs :attr:`step_s`, then :meth:`pump`."""
        self.board.run_until(self.board.now + seconds_to_cycles(self.step_s))
        self.pump(on_event)

    def serve(self, seconds: float, on_event: EventSink | None = None) -> None:
        """The host's link loop for at least ``seconds``, in whole periods."""
        end = self.board.now + seconds_to_cycles(seconds)
        while self.board.now < end:
            self.step(on_event)

    # --- the test as the host -------------------------------------------------------------

    def send(self, message: Message | Enable | Disable, cycle: int | None = None) -> int:
        """Put ``message`` on the RX pin (now, or at ``cycle``); returns its STOP's cycle."""
        self.conn.send(message, self.now_s)
        return self.write(self.conn.data_to_send(), cycle)

    def enable(self) -> int:
        return self.send(Enable())

    def disable(self) -> int:
        return self.send(Disable())

    def collect(self, event: object) -> None:
        """File ``event`` under :attr:`telemetry`, :attr:`replies` or :attr:`other`."""
        if isinstance(event, Telemetry):
            self.telemetry.append(event)
        elif isinstance(event, ParamAck | ParamNack):
            self.replies.append(event)
        elif not isinstance(event, BoardFound):
            self.other.append(event)

    def drain(self) -> None:
        """Collect every event from what the board finished sending by now (no timer fired,
        nothing written)."""
        for event in self.receive():
            self.collect(event)

    def run(self, seconds: float, step_ms: int = 10) -> None:
        """Advance exactly ``seconds`` in slices of at most ``step_ms``, draining the TX pin
        after each slice and sending ``RE`` on schedule while :attr:`keep_enabled`."""
        end = self.board.now + round(seconds * CLOCK_HZ)
        while self.board.now < end:
            if self.keep_enabled and self.board.now >= self._next_re:
                self.enable()
                self._next_re = self.board.now + RE_EVERY_MS * MS
            target = min(end, self.board.now + step_ms * MS)
            if self.keep_enabled:
                target = min(target, max(self._next_re, self.board.now + 1))
            self.board.run_until(target)
            self.drain()

    def run_to(self, cycle: int) -> None:
        self.run((cycle - self.board.now) / CLOCK_HZ, step_ms=1)

    def start_enabled(self) -> None:
        self.keep_enabled = True
        self._next_re = self.board.now

    def request(self, message: ParamSet | ParamGet) -> ParamAck | ParamNack:
        """Send one request and return the board's one reply (PA or PN)."""
        before = len(self.replies)
        self.send(message)
        self.run(0.003, step_ms=1)
        new = self.replies[before:]
        assert len(new) == 1, f"expected one reply to {message}, got {new}"
        return new[0]

    def set(self, param_id: int, channel: int, value_type: int,
            value: int | float) -> ParamAck | ParamNack:
        return self.request(ParamSet(param_id, channel, value_type, value))

    def get(self, param_id: int, channel: int) -> ParamAck | ParamNack:
        return self.request(ParamGet(param_id, channel))

    def references(self, ref_a: float, ref_b: float) -> int:
        return self.send(References(ref_a, ref_b))

    def telemetry_since(self, cycle: int) -> list[Telemetry]:
        t_us = cycle // 100
        return [tm for tm in self.telemetry if tm.t_us >= t_us]


# --- reading what the cable carried -------------------------------------------------------

def content_of(message: Telemetry) -> bytes:
    """The frame content a delivered Telemetry stands for (its fields as received)."""
    assert message.counter is not None, "a received message always has its counter"
    return encode_message(message, message.counter)


def body_of(content: bytes) -> bytes:
    return content[7:]


@dataclass
class StepFigures:
    overshoot: float  #: fraction of the step
    settling_s: float  #: last time outside the ±band, from the step
    final: float


def step_figures(samples: list[tuple[float, float]], start: float, reference: float,
                 band: float = 0.02) -> StepFigures:
    """Overshoot and settling time of ``(time_s, value)`` samples for a step from 0 to
    ``reference`` at ``start``."""
    after = [(t - start, v) for t, v in samples if t >= start]
    peak = max(v / reference for _, v in after)
    limit = band * abs(reference)
    last = 0.0
    for t, v in after:
        if abs(v - reference) > limit:
            last = t
    return StepFigures(max(0.0, peak - 1.0), last, after[-1][1])


def counts_floor(angle_deg: float, counts_per_turn: int) -> int:
    return math.floor(angle_deg * counts_per_turn / 360.0)


# --- the robot ----------------------------------------------------------------------------

STEP_MS = 1
CONTROL_EVERY_MS = 10  #: RV every 10 ms, as the robot issue's scenario


@dataclass
class RobotSim:
    """An emulated robot, a :class:`Cable` per board, and the host's robot parts, stepped
    1 ms at a time."""

    robot: EmulatedRobot
    description: RobotDescription
    odometry: Odometry
    cables: dict[str, Cable] = field(default_factory=dict)
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
        for name, board in robot.boards.items():
            conn = Connection()
            conn.start(0.0)
            sim.cables[name] = Cable(board, conn)
        sim._configure()
        return sim

    @property
    def now(self) -> float:
        return self.now_ms / 1000.0

    def _configure(self) -> None:
        """Telemetry on, enabled; resolution as the boards report it (their defaults)."""
        streaming = lookup("GetDataPeriodical")
        for name, cable in self.cables.items():
            cable.conn.set_param(streaming, 0, 1, self.now)
            cable.conn.enable(self.now)
            for wheel in self.description.wheels:
                if wheel.board == name:
                    pulses = cable.firmware.value("IncSenzRes", wheel.channel)
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
            references: dict[str, list[float]] = {b: [0.0, 0.0] for b in self.cables}
            for wheel in self.description.wheels:
                side = self.wheels[0] if wheel.left else self.wheels[1]
                references[wheel.board][wheel.channel - 1] = side * wheel.forward
            for board, (ref_a, ref_b) in references.items():
                self.cables[board].conn.send(References(ref_a, ref_b), self.now)
            return
        command = wheel_command(self.description, *self.command)
        for board, (ref_a, ref_b) in command.references.items():
            self.cables[board].conn.send(References(ref_a, ref_b), self.now)

    def run(self, seconds: float, control: Callable[[RobotSim], None] | None = None) -> None:
        """Advance ``seconds``; ``control(sim)`` every control period (before the RV). Each
        step the host's links fire their timers and write, the robot runs, the host reads."""
        for _ in range(round(seconds * 1000 / STEP_MS)):
            if self.now_ms % CONTROL_EVERY_MS == 0:
                if control is not None:
                    control(self)
                self._send_command()
            for cable in self.cables.values():
                cable.fire_timer()
                cable.flush()
            self.now_ms += STEP_MS
            self.robot.run_until(ms(self.now_ms))
            for name, cable in self.cables.items():
                samples = [e for e in cable.receive() if isinstance(e, Telemetry)]
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
            latest = self.cables[wheel.board].conn.latest_telemetry
            assert latest is not None
            out[wheel.name] = (latest.a if wheel.channel == CHANNEL_A else latest.b).speed
        return out
