"""The MuJoCo model (MJCF) of a described robot on a surface (:func:`mjcf`).

The chassis (a box of the description's size and mass, its centre of mass where the seed's
scales put the robot's) on a free joint; per wheel, two hinges about the axle: the motor's
rotor and the wheel, coupled by the gearbox's compliance (a fixed tendon), with the
parameters of :func:`fpgaemu.motor.drive_train`, so that a wheel in the air answers its duty
as the seed's identified model does. Each tyre touches the ground at one point (a sphere of
the wheel's radius: one contact per wheel keeps the solver fast), through an explicit
contact pair with the surface's sliding, torsional and rolling friction (MuJoCo's elliptic
cones)."""

from __future__ import annotations

import math
from collections.abc import Mapping

from fpgaemu.motor import DriveTrain
from fpgaemu.physics.drives import worm_hold_nm
from fpgaemu.physics.surfaces import Surface
from fpgaemu.timeline import CLOCK_HZ, ms
from fpgalink.protocol.robot import RobotDescription, WheelMount

__all__ = ["ROTOR_MASS", "STEP_CYCLES", "mjcf"]

#: The physics step: two board periods (1 ms each), so board ticks fall on step edges.
STEP_CYCLES = ms(2)
#: The rotor body's own mass (kg; its inertia is the joint's armature), taken off the
#: chassis's so the robot weighs what its description says.
ROTOR_MASS = 0.05


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
    wheels = "".join(_wheel(w, mount[w.name], description, train) for w in description.wheels)
    ground_names, ground_xml = _grounds(surface, radius)
    pairs = "".join(_contact(w.name, ground, surface)
                    for w in description.wheels for ground in ground_names)
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
      {wheels}
    </body>
  </worldbody>
  <tendon>{"".join(_gearbox(w.name, train) for w in description.wheels)}</tendon>
  <equality>{"".join(f'<joint name="{w.name}_blocked" joint1="{w.name}" active="false"/>'
                      for w in description.wheels)}</equality>
  <actuator>{"".join(f'<motor name="{w.name}_motor" joint="{w.name}_rotor"/>'
                     for w in description.wheels)}</actuator>
  <contact>{pairs}</contact>
  <sensor><gyro name="gyro" site="imu"/><accelerometer name="accelerometer" site="imu"/></sensor>
</mujoco>
"""


def _wheel(w: WheelMount, sign: int, description: RobotDescription, train: DriveTrain) -> str:
    """A wheel's two bodies on base_link: the motor's rotor, and the wheel with its tyre
    (the contact) and its picture; ``sign`` (±1) the motor's positive rotation about +y."""
    body = description.body
    radius = description.wheel_radius
    wheel_inertia = 0.5 * body.wheel_mass * radius**2
    lateral = body.wheel_mass * (3 * radius**2 + body.wheel_width**2) / 12
    axis = f"0 {sign} 0"
    return (
        f'<body name="{w.name}_rotor" pos="{_v((w.x, w.y, 0.0))}">'
        f'<joint name="{w.name}_rotor" axis="{axis}" armature="{_f(train.rotor_inertia)}" '
        f'damping="{_f(train.rotor_friction)}"/>'
        f'<inertial pos="0 0 0" mass="{_f(ROTOR_MASS)}" diaginertia="1e-4 1e-4 1e-4"/>'
        '</body>'
        f'<body name="{w.name}_link" pos="{_v((w.x, w.y, 0.0))}">'
        f'<joint name="{w.name}" axis="{axis}" frictionloss="{_f(worm_hold_nm(train))}" '
        f'armature="{_f(max(train.wheel_inertia - wheel_inertia, 0.0))}"/>'
        f'<inertial pos="0 0 0" mass="{_f(body.wheel_mass)}" '
        f'diaginertia="{_v((lateral, wheel_inertia, lateral))}"/>'
        f'<geom name="{w.name}_tyre" type="sphere" size="{_f(radius)}" contype="2" '
        'conaffinity="0" group="3"/>'
        # What a picture shows (no contact, no mass): the wheel as it is.
        f'<geom name="{w.name}_wheel" type="cylinder" '
        f'size="{_f(radius)} {_f(body.wheel_width / 2)}" zaxis="0 1 0" contype="0" '
        'conaffinity="0" mass="0" group="1" rgba="0.12 0.12 0.12 1"/></body>')


def _gearbox(wheel: str, train: DriveTrain) -> str:
    """The gearbox's compliance between a wheel's rotor and the wheel: a fixed tendon."""
    return (f'<fixed name="{wheel}_gearbox" stiffness="{_f(train.stiffness)}" '
            f'damping="{_f(train.damping)}"><joint joint="{wheel}_rotor" coef="1"/>'
            f'<joint joint="{wheel}" coef="-1"/></fixed>')


def _contact(wheel: str, ground: str, surface: Surface) -> str:
    """The contact pair of a wheel's tyre and a ground geom, with the surface's friction."""
    friction = (surface.sliding, surface.sliding, surface.torsional,
                surface.rolling, surface.rolling)
    # Rolling friction (condim 6) triples the contact solver's cost: only where the ground
    # has any.
    condim = 6 if surface.rolling else 4
    return (f'<pair geom1="{wheel}_tyre" geom2="{ground}" '
            f'condim="{condim}" friction="{_v(friction)}"/>')


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
