"""The robot's body on a physics engine (MuJoCo): a rigid chassis on four wheels whose
motors are the boards' own (:class:`fpgaemu.motor.WheelDrive`), on a ground of a chosen
surface — the body the kinematic one (:mod:`fpgaemu.body`) is not: the wheels slip, the
ground loads them, the body pitches and rolls, and an IMU feels it.

**Model** (generated from the robot description, :func:`mjcf`): the chassis (a box of the
description's size and mass, its centre of mass where the seed's scales put the robot's)
on a free joint; per wheel, two hinges about the axle: the motor's rotor and the wheel,
coupled by the gearbox's compliance (a fixed tendon), with the parameters of
:func:`fpgaemu.motor.drive_train`, so that a wheel in the air answers its duty as the
seed's identified model does. The winding's torque (from the board's PWM through the
motor's current, :meth:`WheelDrive.torque_over`) drives the rotor. Each tyre touches the
ground at one point (a sphere of the wheel's radius: one contact per wheel keeps the solver
fast), through an explicit contact pair with the surface's sliding, torsional and rolling
friction (MuJoCo's elliptic cones).

**Surfaces** (:data:`SURFACES`): contact parameters per ground, calibrated against the
seed's §3.6 runs (docs/robot.md); gravel has a seeded stochastic friction field (the
coefficient under each wheel varies smoothly over the ground, re-read every
:data:`FIELD_PERIOD_STEPS` steps), so the centre of an in-place turn wanders as in §3.6.3;
``slope45-sand`` tilts the ground by 45° (the robot faces uphill); ``stairs`` puts three
40° steps (0.17 m rise, 0.20 m run) ahead of the robot, going down.

**Stepping**: the physics step is :data:`STEP_CYCLES` (2 ms, two board periods); each step
the drives' torques over it are applied, then the boards run through it with the wheels'
angles interpolated (:meth:`PhysicsBody.advance`). An unpowered wheel slower than
:data:`HOLD_BAND_DPS` is held by its worm gear, which self-locks: the worm wheel cannot turn
the worm. The lock is at the mesh, on the wheel's axle, so it is friction on the wheel's
joint against the chassis (up to :data:`HOLD_SHARE` of the stall torque), not on the rotor:
the gearbox's compliance sits between the rotor and the worm, and a wheel held only through
it rang on it (a robot disabled at 0.2 m/s rocked ±2 cm/s for 1.5 s). With every wheel held
and the body still, the physics sleeps until a wheel is driven again, so a robot at rest
costs nothing.

**IMU** at the seed's ``ImuALink``: MuJoCo's gyro and accelerometer, averaged over the time
since the last reading (an IMU's output filter), plus seeded noise and bias (:class:`Imu`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from fpgaemu.motor import MAX_DUTY, DriveTrain, WheelDrive
from fpgaemu.timeline import CLOCK_HZ, ms
from fpgalink.protocol.robot import WHEEL_NAMES, Pose, RobotDescription, wrap_angle

__all__ = [
    "FIELD_PERIOD_STEPS",
    "HOLD_BAND_DPS",
    "STEP_CYCLES",
    "SURFACES",
    "Imu",
    "ImuReading",
    "PhysicsBody",
    "Surface",
    "available",
    "mjcf",
    "render",
    "why_unavailable",
]

#: The physics step: two board periods (1 ms each), so board ticks fall on step edges.
STEP_CYCLES = ms(2)
#: The gravel's friction field is re-read under the wheels this often (20 ms: a wheel at full
#: speed moves 6 mm).
FIELD_PERIOD_STEPS = 10
#: An unpowered wheel turning slower than this is held by its worm gear (deg/s): above it the
#: rotor's own momentum still drives the worm forward, which a worm gear passes.
HOLD_BAND_DPS = 10.0
#: The holding torque of an unpowered worm gear at the wheel's axle (friction on the wheel's
#: joint), as a share of the motor's stall torque: far above any load the ground puts on a
#: wheel of this robot (20 N·m each on the 45° slope), so the tyres slide before it yields.
HOLD_SHARE = 0.5
#: Below this (rad/s, m/s) on every degree of freedom, with every wheel held, the body is
#: still and the physics sleeps.
SLEEP_SPEED = 2e-3
STANDARD_GRAVITY = 9.81
#: The rotor body's own mass (kg; its inertia is the joint's armature), taken off the
#: chassis's so the robot weighs what its description says.
ROTOR_MASS = 0.05
#: The IMU's mean is taken over every this many steps (8 ms: far above its output rate).
IMU_PERIOD_STEPS = 4
_DEGREES = 180.0 / math.pi
#: At most this long (s) to let the body settle on the ground before time starts.
SETTLE_S = 3.0


def why_unavailable() -> str | None:
    """Why the physics body cannot run here (``None`` when it can)."""
    try:
        import mujoco  # noqa: F401
    except ImportError as exc:
        return f"MuJoCo is not installed ({exc}); pip install 'fpgalink[physics]'"
    return None


def available() -> bool:
    return why_unavailable() is None


@dataclass(frozen=True, slots=True)
class Surface:
    """A ground and its contact with the tyres, in MuJoCo's terms: sliding friction
    (dimensionless), torsional and rolling friction (m: the torque per newton of load that
    resists spinning on the spot and rolling)."""

    name: str
    sliding: float
    torsional: float = 0.0
    rolling: float = 0.0
    #: the friction field's relative spread (0: uniform) and correlation length (m)
    field_spread: float = 0.0
    field_length: float = 0.3
    slope_deg: float = 0.0  #: the ground rises ahead of the robot
    steps: int = 0  #: steps down ahead of the robot
    step_rise: float = 0.17
    step_run: float = 0.20
    note: str = ""


#: The grounds the physics body knows (docs/robot.md: calibration and assumptions).
SURFACES: dict[str, Surface] = {s.name: s for s in (
    Surface("gravel", sliding=0.8, torsional=0.005, field_spread=0.10, field_length=0.4,
            note="loose 0.8–1.1 cm gravel over soil (§3.6.2–3.6.6): the stones roll under "
                 "the tyres (little torsional friction), and cover the ground unevenly "
                 "(a friction field)"),
    Surface("marble", sliding=0.8, torsional=0.08,
            note="a smooth marble floor (§3.6.4): the tyres' whole contact patch grips, so "
                 "turning on the spot meets more torsional friction"),
    Surface("grass", sliding=0.6, torsional=0.02, rolling=0.01, field_spread=0.15,
            field_length=0.6,
            note="short grass (§3.6.6 drove on it; no figure given): assumed"),
    Surface("slope45-sand", sliding=1.05, torsional=0.02, rolling=0.005, slope_deg=45.0,
            note="a 45° sandy slope with stones up to 4 cm (§3.6.7); sinking not modelled"),
    Surface("stairs", sliding=0.8, torsional=0.005, steps=3,
            note="three 40° steps down, 0.17 m rise, 0.20 m run (§3.6.8: a 40° stair)"),
)}


def _f(value: float) -> str:
    return f"{value:.6g}"


def _v(values: tuple[float, ...] | list[float]) -> str:
    return " ".join(_f(v) for v in values)


def mjcf(description: RobotDescription, surface: Surface, train: DriveTrain,
         mount: Mapping[str, int], *, lifted: bool = False,
         step_s: float = STEP_CYCLES / CLOCK_HZ) -> str:
    """The MuJoCo model (MJCF) of the described robot on ``surface``: base_link at the
    centre of the wheel axles, REP-103. ``mount[wheel]`` (±1) is the sign of the motor's
    positive rotation about the wheel's +y axis (positive about +y rolls the robot forward).
    ``lifted``: the chassis fixed in the air, the wheels free (the motor test bench)."""
    body = description.body
    radius = description.wheel_radius
    cx, cy, cz = body.chassis_com(description.wheels)
    ixx, iyy, izz = body.chassis_inertia
    length, width, height = body.chassis
    wheel_inertia = 0.5 * body.wheel_mass * radius**2
    lateral = body.wheel_mass * (3 * radius**2 + body.wheel_width**2) / 12
    hold = HOLD_SHARE * train.stall_torque_nm
    wheels, tendons, actuators, pairs = [], [], [], []
    for w in description.wheels:
        axis = f"0 {mount[w.name]} 0"
        wheels.append(
            f'<body name="{w.name}_rotor" pos="{_v((w.x, w.y, 0.0))}">'
            f'<joint name="{w.name}_rotor" axis="{axis}" armature="{_f(train.rotor_inertia)}" '
            f'damping="{_f(train.rotor_friction)}"/>'
            f'<inertial pos="0 0 0" mass="{_f(ROTOR_MASS)}" diaginertia="1e-4 1e-4 1e-4"/>'
            '</body>'
            f'<body name="{w.name}_link" pos="{_v((w.x, w.y, 0.0))}">'
            f'<joint name="{w.name}" axis="{axis}" frictionloss="{_f(hold)}" '
            f'armature="{_f(max(train.wheel_inertia - wheel_inertia, 0.0))}"/>'
            f'<inertial pos="0 0 0" mass="{_f(body.wheel_mass)}" '
            f'diaginertia="{_v((lateral, wheel_inertia, lateral))}"/>'
            f'<geom name="{w.name}_tyre" type="sphere" size="{_f(radius)}" contype="2" '
            'conaffinity="0" group="3"/>'
            # What a picture shows (no contact, no mass): the wheel as it is.
            f'<geom name="{w.name}_wheel" type="cylinder" '
            f'size="{_f(radius)} {_f(body.wheel_width / 2)}" zaxis="0 1 0" contype="0" '
            'conaffinity="0" mass="0" group="1" rgba="0.12 0.12 0.12 1"/></body>')
        tendons.append(
            f'<fixed name="{w.name}_gearbox" stiffness="{_f(train.stiffness)}" '
            f'damping="{_f(train.damping)}"><joint joint="{w.name}_rotor" coef="1"/>'
            f'<joint joint="{w.name}" coef="-1"/></fixed>')
        actuators.append(f'<motor name="{w.name}_motor" joint="{w.name}_rotor"/>')
    ground_names, ground_xml = _grounds(surface, radius)
    for w in description.wheels:
        for ground in ground_names:
            friction = (surface.sliding, surface.sliding, surface.torsional,
                        surface.rolling, surface.rolling)
            # Rolling friction (condim 6) triples the contact solver's cost: only where
            # the ground has any.
            condim = 6 if surface.rolling else 4
            pairs.append(f'<pair geom1="{w.name}_tyre" geom2="{ground}" '
                         f'condim="{condim}" friction="{_v(friction)}"/>')
    start = _start(surface, radius, lifted)
    root = "" if lifted else '<freejoint name="root"/>'
    return f"""<mujoco model="{description.name}">
  <compiler angle="radian"/>
  <option timestep="{_f(step_s)}" integrator="implicitfast" cone="elliptic" impratio="1"
          tolerance="1e-6"/>
  <size memory="4M"/>
  <visual><headlight ambient="0.35 0.35 0.35" diffuse="0.5 0.5 0.5"/></visual>
  <asset>
    <texture name="ground" type="2d" builtin="checker" width="256" height="256"
             rgb1="0.50 0.46 0.40" rgb2="0.42 0.38 0.33"/>
    <material name="ground" texture="ground" texrepeat="8 8" texuniform="true"/>
  </asset>
  <worldbody>
    <light pos="0 -2 4" dir="0 0.5 -1"/>
    {ground_xml}
    <body name="base_link" pos="{_v(start[0])}" quat="{_v(start[1])}">
      {root}
      <inertial pos="{_v((cx, cy, cz))}" mass="{_f(body.chassis_mass - 4 * ROTOR_MASS)}"
                diaginertia="{_v((ixx, iyy, izz))}"/>
      <geom name="chassis" type="box" size="{_v((length / 2, width / 2, height / 2))}"
            pos="0 0 {_f(body.chassis_z)}" mass="0" contype="1" conaffinity="0"
            rgba="0.55 0.6 0.65 1"/>
      <site name="imu" pos="{_v(body.imu)}" size="0.02"/>
      {"".join(wheels)}
    </body>
  </worldbody>
  <tendon>{"".join(tendons)}</tendon>
  <equality>{"".join(f'<joint name="{w.name}_blocked" joint1="{w.name}" active="false"/>'
                      for w in description.wheels)}</equality>
  <actuator>{"".join(actuators)}</actuator>
  <contact>{"".join(pairs)}</contact>
  <sensor><gyro name="gyro" site="imu"/><accelerometer name="accelerometer" site="imu"/></sensor>
</mujoco>
"""


def _grounds(surface: Surface, radius: float) -> tuple[list[str], str]:
    """The ground's geoms: their names (each tyre gets a contact pair with each) and XML."""
    out: list[str] = []
    geoms: list[str] = []
    look = 'material="ground"'
    if surface.slope_deg:
        # The plane through the origin, rising ahead (+x): turned about +y by −α.
        a = math.radians(surface.slope_deg)
        quat = (math.cos(-a / 2), 0.0, math.sin(-a / 2), 0.0)
        geoms.append(f'<geom name="ground" type="plane" size="0 0 1" quat="{_v(quat)}" '
                     f'contype="1" conaffinity="3" {look}/>')
        out.append("ground")
    elif surface.steps:
        # A landing ending 5 cm ahead of the front tyres, then the steps down, then the floor.
        edge = 0.05 + 0.29 + radius
        geoms.append(f'<geom name="landing" type="box" size="5 5 0.5" '
                     f'pos="{_f(edge - 5)} 0 -0.5" contype="1" conaffinity="3" {look}/>')
        out.append("landing")
        for i in range(1, surface.steps + 1):
            top = -i * surface.step_rise
            x0 = edge + (i - 1) * surface.step_run
            geoms.append(f'<geom name="step{i}" type="box" '
                         f'size="{_f(surface.step_run / 2)} 5 0.5" '
                         f'pos="{_f(x0 + surface.step_run / 2)} 0 {_f(top - 0.5)}" '
                         f'contype="1" conaffinity="3" {look}/>')
            out.append(f"step{i}")
        floor = -(surface.steps + 1) * surface.step_rise
        geoms.append(f'<geom name="ground" type="plane" size="0 0 1" pos="0 0 {_f(floor)}" '
                     f'contype="1" conaffinity="3" {look}/>')
        out.append("ground")
    else:
        geoms.append(f'<geom name="ground" type="plane" size="0 0 1" contype="1" '
                     f'conaffinity="3" {look}/>')
        out.append("ground")
    return out, "".join(geoms)


def _start(surface: Surface, radius: float, lifted: bool) -> tuple[tuple[float, ...],
                                                                     tuple[float, ...]]:
    """base_link's starting position and orientation (w, x, y, z): wheels on the ground."""
    if lifted:
        return (0.0, 0.0, radius + 1.0), (1.0, 0.0, 0.0, 0.0)
    if surface.slope_deg:
        a = math.radians(surface.slope_deg)
        return ((-math.sin(a) * radius, 0.0, math.cos(a) * radius),
                (math.cos(-a / 2), 0.0, math.sin(-a / 2), 0.0))
    return (0.0, 0.0, radius), (1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class ImuReading:
    """One IMU sample in the IMU's frame (base_link's axes): rad/s and m/s², averaged over
    the time since the previous reading, noise and bias included."""

    t: float  #: s of emulated time
    angular_velocity: tuple[float, float, float]
    linear_acceleration: tuple[float, float, float]
    #: the body's true orientation (w, x, y, z), for a consumer that wants one
    orientation: tuple[float, float, float, float]
    #: the noise's variance per axis in this reading ((rad/s)², (m/s²)²)
    angular_velocity_variance: float = 0.0
    linear_acceleration_variance: float = 0.0

    def record(self) -> dict[str, Any]:
        return {"t": self.t, "angular_velocity": list(self.angular_velocity),
                "linear_acceleration": list(self.linear_acceleration),
                "orientation": list(self.orientation),
                "angular_velocity_variance": self.angular_velocity_variance,
                "linear_acceleration_variance": self.linear_acceleration_variance}


@dataclass(frozen=True, slots=True)
class Imu:
    """The IMU's errors. The seed names no part (an ESP8266 reads "the IMU" over SPI) and
    gives no figures, only that the gyro's yaw rate is noisier than the LIDAR's and more so
    when turning faster (§3.6.2–3.6.4); these are an MPU-9250-class MEMS part's datasheet
    figures at a 50 Hz output (docs/robot.md)."""

    gyro_noise: float = math.radians(0.1)  #: rad/s, one sigma per reading
    gyro_bias: float = math.radians(0.5)  #: rad/s, one sigma of the constant bias per axis
    #: rad/s of extra noise per rad/s of yaw rate (vibration while turning, §3.6.3)
    gyro_rate_noise: float = 0.02
    accel_noise: float = 0.03  #: m/s², one sigma per reading
    accel_bias: float = 0.05  #: m/s², one sigma of the constant bias per axis


class PhysicsBody:
    """The robot on MuJoCo. :meth:`advance` steps the physics over one step with the
    drives' torques and hands each drive its wheel's motion; read :meth:`pose`,
    :meth:`attitude`, :meth:`twist`, :meth:`read_imu` (:class:`fpgaemu.robot.EmulatedRobot`
    makes its truth of them)."""

    def __init__(self, description: RobotDescription, drives: Mapping[str, WheelDrive],
                 mount: Mapping[str, int], surface: str = "gravel", *, seed: int = 0,
                 step_cycles: int = STEP_CYCLES, lifted: bool = False,
                 imu: Imu | None = None) -> None:
        import mujoco

        if surface not in SURFACES:
            raise ValueError(f"surface {surface!r}: the physics body knows "
                             f"{', '.join(SURFACES)}")
        if step_cycles <= 0 or step_cycles % ms(1):
            raise ValueError("the physics step must be a whole number of milliseconds (the "
                             f"board period), got {step_cycles} cycles")
        self._mujoco = mujoco
        self.description = description
        self.surface = SURFACES[surface]
        self.step_cycles = step_cycles
        self.dt = step_cycles / CLOCK_HZ
        self.lifted = lifted
        names = [w.name for w in description.wheels]
        self.drives = [drives[n] for n in names]
        train = self.drives[0].train
        self.xml = mjcf(description, self.surface, train, mount, lifted=lifted, step_s=self.dt)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        model = self.model
        self._wheel_q = [int(model.joint(n).qposadr[0]) for n in names]
        self._rotor_q = [int(model.joint(f"{n}_rotor").qposadr[0]) for n in names]
        self._rotor_dof = [int(model.joint(f"{n}_rotor").dofadr[0]) for n in names]
        self._wheel_dof = [int(model.joint(n).dofadr[0]) for n in names]
        self._gather = np.array(self._wheel_q + self._rotor_q)
        self._wheel_bodies = np.array([int(model.body(f"{n}_link").id) for n in names])
        tyres = [next(n for g in pair if (n := model.geom(int(g)).name).endswith("_tyre"))
                 for pair in zip(model.pair_geom1, model.pair_geom2, strict=True)]
        self._pair_wheel = np.array([names.index(tyre[:-5]) for tyre in tyres])
        self._base_friction = model.pair_friction[:, :2].copy()
        self._hold = HOLD_SHARE * train.stall_torque_nm
        motor = train.motor
        tau = motor.inductance_h / motor.resistance_ohm
        #: for the drives' torque over a step (WheelDrive.torque_over, written out)
        self._electrics = (motor.supply_v, motor.resistance_ohm, train.torque_constant,
                           tau / self.dt * (1.0 - math.exp(-self.dt / tau)))
        self._held = [True] * len(names)
        self._stalled = [False] * len(names)
        for drive in self.drives:
            drive.on_stall = self._stall_changed
        angles = self.data.qpos[self._gather].tolist()
        self._angles = angles[:len(names)]
        self._rotors = angles[len(names):]
        self.cycle = 0
        self.steps = 0
        self.asleep = False
        self.distance = 0.0
        self._last_xy = (float(self.data.qpos[0]), float(self.data.qpos[1])) if not lifted \
            else (0.0, 0.0)
        self._imu_sum = np.zeros(6)
        self._imu_steps = 0
        self.imu = imu or Imu()
        self._rng = np.random.default_rng([seed, 0x1A0])
        self._gyro_bias = self._rng.normal(0.0, self.imu.gyro_bias, 3)
        self._accel_bias = self._rng.normal(0.0, self.imu.accel_bias, 3)
        self._field = _FrictionField(seed, self.surface)
        self._settle()
        for drive in self.drives:  # a wheel stalled before the body existed (a fault)
            if drive.stalled:
                self._stall_changed(drive)

    def _settle(self) -> None:
        """Let the body come to rest on its wheels (held) before time starts: the ground
        takes its weight, so the robot starts still and the IMU reads gravity."""
        if self._field.active:
            self._update_friction()
        for _ in range(round(SETTLE_S / self.dt)):
            self._mujoco.mj_step(self.model, self.data)
            if float(np.abs(self.data.qvel).max()) < SLEEP_SPEED / 10:
                break
        angles = self.data.qpos[self._gather].tolist()
        self._angles = angles[:len(self.drives)]
        self._rotors = angles[len(self.drives):]
        if not self.lifted:
            self._last_xy = (float(self.data.qpos[0]), float(self.data.qpos[1]))
        self._fall_asleep()

    def place(self, pose: Pose) -> None:
        """Put the robot at ``pose`` on the ground (before it moves), at rest."""
        if self.lifted:
            raise ValueError("a lifted body stays where it is")
        q = self.data.qpos
        half = pose.theta / 2
        _, pitch, _ = _euler(q[3:7])
        # The heading about the world's z, the settled pitch kept (a slope's).
        turn = np.array([math.cos(half), 0.0, 0.0, math.sin(half)])
        tilt = np.array([math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0])
        out = np.empty(4)
        self._mujoco.mju_mulQuat(out, turn, tilt)
        q[0], q[1] = pose.x, pose.y
        q[3:7] = out
        self.data.qvel[:] = 0.0
        self._mujoco.mj_forward(self.model, self.data)
        self._settle()

    # --- stepping -------------------------------------------------------------------------

    def advance(self, cycle1: int) -> None:
        """One physics step, from :attr:`cycle` to ``cycle1`` (a whole number of steps when
        asleep), then each drive follows its wheel."""
        cycle0 = self.cycle
        drives = self.drives
        if self.asleep:
            for drive in drives:
                if drive.duty or drive.current:
                    self._wake()
                    break
            else:
                self.cycle = cycle1
                for drive, angle in zip(drives, self._angles, strict=True):
                    drive.follow_physics(cycle0, cycle1, math.degrees(angle), 0.0, 0.0)
                return
        if cycle1 - cycle0 != self.step_cycles:
            raise ValueError(f"an awake physics body steps {self.step_cycles} cycles at a "
                             f"time, not {cycle1 - cycle0}")
        model, data, dt = self.model, self.data, self.dt
        held, stalled = self._held, self._stalled
        # The drives' torques over the step (WheelDrive.torque_over) and the worm gears'
        # holds, written out: this runs every physics step.
        supply, resistance, k, share = self._electrics
        torques = []
        powered = False
        for i, drive in enumerate(drives):
            duty = drive.duty
            if duty:
                powered = True
            hold = not duty and -HOLD_BAND_DPS < drive.wheel_speed_dps < HOLD_BAND_DPS
            if hold != held[i] and not stalled[i]:
                held[i] = hold
                model.dof_frictionloss[self._wheel_dof[i]] = self._hold if hold else 0.0
            steady = (supply * duty / MAX_DUTY - k * drive.rotor_speed) / resistance
            torques.append(k * (steady + (drive.current - steady) * share))
        data.ctrl[:] = torques
        steps = self.steps
        if not steps % FIELD_PERIOD_STEPS:
            if self._field.active:
                self._update_friction()
            if not self.lifted:
                self._track_distance()
        self._mujoco.mj_step(model, data)
        self.steps = steps + 1
        self.cycle = cycle1
        if not steps % IMU_PERIOD_STEPS:
            self._imu_sum += data.sensordata[:6]
            self._imu_steps += 1
        positions = data.qpos[self._gather].tolist()
        n = len(drives)
        wheels, rotors = positions[:n], positions[n:]
        angles, last_rotors = self._angles, self._rotors
        to_degrees = _DEGREES
        for i, drive in enumerate(drives):
            drive.follow_physics(cycle0, cycle1, wheels[i] * to_degrees,
                                 (wheels[i] - angles[i]) * to_degrees / dt,
                                 (rotors[i] - last_rotors[i]) / dt)
        self._angles, self._rotors = wheels, rotors
        if not powered and all(held):
            self._maybe_sleep()

    def _update_friction(self) -> None:
        xy = self.data.xpos[self._wheel_bodies, :2]
        scale = self._field.scale(xy)[self._pair_wheel]
        self.model.pair_friction[:, :2] = self._base_friction * scale[:, None]

    def _track_distance(self) -> None:
        x, y = float(self.data.qpos[0]), float(self.data.qpos[1])
        self.distance += math.hypot(x - self._last_xy[0], y - self._last_xy[1])
        self._last_xy = (x, y)

    def _maybe_sleep(self) -> None:
        if float(np.abs(self.data.qvel).max()) < SLEEP_SPEED:
            self._fall_asleep()

    def _fall_asleep(self) -> None:
        """Every wheel held and the body still: nothing moves until a wheel is driven."""
        self.data.qvel[:] = 0.0
        self.asleep = True
        for drive in self.drives:
            drive.rotor_speed = 0.0
            drive.wheel_speed_dps = 0.0
            drive.body_asleep = True

    def _wake(self) -> None:
        self.asleep = False
        for drive in self.drives:
            drive.body_asleep = False

    def _stall_changed(self, drive: WheelDrive) -> None:
        """A blocked wheel (``WheelDrive.stall``, the ``wheel-stuck`` fault): its joint held
        where it is by an equality constraint until released."""
        i = self.drives.index(drive)
        self._stalled[i] = drive.stalled
        name = self.description.wheels[i].name
        blocked = self.model.equality(f"{name}_blocked").id
        if drive.stalled:
            self.model.eq_data[blocked, 0] = self.data.qpos[self._wheel_q[i]]
        self.data.eq_active[blocked] = 1 if drive.stalled else 0
        self._wake()

    # --- reading ---------------------------------------------------------------------------

    @property
    def t(self) -> float:
        return self.cycle / CLOCK_HZ

    def pose(self) -> Pose:
        q = self.data.qpos
        return Pose(float(q[0]), float(q[1]), _yaw(q[3:7]))

    def attitude(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw), rad (REP-103: pitch positive nose down)."""
        return _euler(self.data.qpos[3:7])

    def twist(self) -> tuple[float, float]:
        """(forward speed m/s in the body's heading, yaw rate rad/s in the world)."""
        v = self.data.qvel
        yaw = _yaw(self.data.qpos[3:7])
        forward = float(v[0]) * math.cos(yaw) + float(v[1]) * math.sin(yaw)
        # The free joint's angular velocity is in the body frame: the world's z component.
        q = self.data.qpos[3:7]
        rotation = np.empty(9)
        self._mujoco.mju_quat2Mat(rotation, q)
        wz = float(rotation[6] * v[3] + rotation[7] * v[4] + rotation[8] * v[5])
        return forward, wz

    def read_imu(self) -> ImuReading:
        """The IMU's reading: the sensors' mean since the previous reading, with noise."""
        if self._imu_steps:
            mean = self._imu_sum / self._imu_steps
        elif self.asleep:
            # Still: no rotation, and the accelerometer feels only the ground holding the
            # body up against gravity: g along the world's z, in the IMU's frame.
            rotation = np.empty(9)
            self._mujoco.mju_quat2Mat(rotation, self.data.qpos[3:7] if not self.lifted
                                      else np.array([1.0, 0.0, 0.0, 0.0]))
            mean = np.concatenate([np.zeros(3), STANDARD_GRAVITY * rotation[6:9]])
        else:
            mean = np.array(self.data.sensordata[:6])
        self._imu_sum[:] = 0.0
        self._imu_steps = 0
        imu = self.imu
        rng = self._rng
        gyro_sigma = imu.gyro_noise + imu.gyro_rate_noise * abs(float(mean[2]))
        gyro = mean[:3] + self._gyro_bias + rng.normal(0.0, gyro_sigma, 3)
        accel = mean[3:] + self._accel_bias + rng.normal(0.0, imu.accel_noise, 3)
        q = self.data.qpos[3:7] if not self.lifted else np.array([1.0, 0.0, 0.0, 0.0])
        return ImuReading(self.t, (float(gyro[0]), float(gyro[1]), float(gyro[2])),
                          (float(accel[0]), float(accel[1]), float(accel[2])),
                          (float(q[0]), float(q[1]), float(q[2]), float(q[3])),
                          gyro_sigma**2, imu.accel_noise**2)

    def wheel_speeds(self) -> dict[str, float]:
        """Each wheel's true speed (deg/s, physical sign)."""
        v = self.data.qvel
        return {w.name: math.degrees(float(v[d]))
                for w, d in zip(self.description.wheels, self._wheel_dof, strict=True)}

    def contact_forces(self) -> dict[str, float]:
        """The ground's normal force on each wheel (N), summed over its contacts."""
        out = dict.fromkeys(WHEEL_NAMES, 0.0)
        force = np.zeros(6)
        model, data = self.model, self.data
        for i in range(data.ncon):
            contact = data.contact[i]
            for geom in (contact.geom1, contact.geom2):
                name = model.geom(int(geom)).name
                if name.endswith("_tyre"):
                    self._mujoco.mj_contactForce(model, data, i, force)
                    out[name[:-5]] += float(force[0])
        return out


def render(body: PhysicsBody, width: int = 640, height: int = 480, *,
           azimuth: float = 135.0, elevation: float = -20.0, distance: float = 2.5
           ) -> np.ndarray[Any, Any]:
    """A picture of the body as it is (RGB, ``height`` × ``width`` × 3), the camera aimed at
    the chassis. Needs an OpenGL MuJoCo can use without a display: ``MUJOCO_GL=egl`` (Mesa's
    software EGL works on a machine without a GPU) or ``osmesa``."""
    import mujoco

    renderer = mujoco.Renderer(body.model, height, width)
    try:
        camera = mujoco.MjvCamera()
        camera.lookat[:] = body.data.xpos[body.model.body("base_link").id]
        camera.azimuth, camera.elevation, camera.distance = azimuth, elevation, distance
        renderer.update_scene(body.data, camera)
        image: np.ndarray[Any, Any] = renderer.render()
        return image
    finally:
        renderer.close()


class _FrictionField:
    """A smooth random field over the ground, seeded: the friction coefficient under a
    point is the surface's times 1 + spread·g(x, y), g a unit-variance Gaussian field with
    the surface's correlation length (random Fourier features), clipped to 0.3–1.7."""

    FEATURES = 48

    def __init__(self, seed: int, surface: Surface) -> None:
        self.active = surface.field_spread > 0.0
        rng = np.random.default_rng([seed, 0xF1E1D])
        self._k = rng.normal(0.0, 1.0 / surface.field_length, (2, self.FEATURES))
        self._phase = rng.uniform(0.0, math.tau, self.FEATURES)
        self._amplitude = math.sqrt(2.0 / self.FEATURES) * surface.field_spread

    def scale(self, xy: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
        g = np.cos(xy @ self._k + self._phase).sum(axis=1) * self._amplitude
        result: np.ndarray[Any, Any] = np.clip(1.0 + g, 0.3, 1.7)
        return result


def _yaw(q: Any) -> float:
    w, x, y, z = (float(v) for v in q)
    return wrap_angle(math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def _euler(q: Any) -> tuple[float, float, float]:
    w, x, y, z = (float(v) for v in q)
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, wrap_angle(yaw)
