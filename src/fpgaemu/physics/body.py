"""The robot on MuJoCo (:class:`PhysicsBody`): the model made from the description
(:mod:`~fpgaemu.physics.model`), stepped with the drives' torques
(:mod:`~fpgaemu.physics.drives`), its tyres on the ground (:mod:`~fpgaemu.physics.contact`)
and its IMU (:mod:`~fpgaemu.physics.imu`), and what it reads: pose, attitude, twist.

**Stepping**: the physics step is :data:`~fpgaemu.physics.model.STEP_CYCLES` (2 ms, two
board periods); each step the drives' torques over it are applied, then the boards run
through it with the wheels' angles interpolated (:meth:`PhysicsBody.advance`). With every
wheel held by its worm gear and the body still, the physics sleeps until a wheel is driven
again, so a robot at rest costs nothing."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from fpgaemu.motor import WheelDrive
from fpgaemu.physics.contact import FIELD_PERIOD_STEPS, TyreContacts
from fpgaemu.physics.drives import DriveCoupling
from fpgaemu.physics.imu import IMU_PERIOD_STEPS, STANDARD_GRAVITY, Imu, ImuReading, ImuSensor
from fpgaemu.physics.model import STEP_CYCLES, mjcf
from fpgaemu.physics.surfaces import SURFACES
from fpgaemu.timeline import CLOCK_HZ, ms
from fpgalink.protocol.robot import Pose, RobotDescription, wrap_angle

__all__ = ["SETTLE_S", "SLEEP_SPEED", "PhysicsBody"]

#: Below this (rad/s, m/s) on every degree of freedom, with every wheel held, the body is
#: still and the physics sleeps.
SLEEP_SPEED = 2e-3
#: At most this long (s) to let the body settle on the ground before time starts.
SETTLE_S = 3.0
#: The orientation a lifted body (fixed in the air, level) reads.
_LEVEL = (1.0, 0.0, 0.0, 0.0)


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
        train = drives[names[0]].train
        self.xml = mjcf(description, self.surface, train, mount, lifted=lifted, step_s=self.dt)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        #: the wheels' drives, coupled to their joints
        self.wheels = DriveCoupling(self.model, self.data, names, [drives[n] for n in names],
                                    self.dt)
        for drive in self.wheels.drives:
            drive.on_stall = self._stall_changed
        self.cycle = 0
        self.steps = 0
        self.asleep = False
        self.distance = 0.0
        self._last_xy = self._xy() if not lifted else (0.0, 0.0)
        self.imu = ImuSensor(imu or Imu(), seed)
        self.tyres = TyreContacts(mujoco, self.model, self.data, names, self.surface, seed)
        self._settle()
        for drive in self.wheels.drives:  # a wheel stalled before the body existed (a fault)
            if drive.stalled:
                self._stall_changed(drive)

    @property
    def drives(self) -> list[WheelDrive]:
        """The wheels' drives, in the description's wheel order."""
        return self.wheels.drives

    def _xy(self) -> tuple[float, float]:
        return float(self.data.qpos[0]), float(self.data.qpos[1])

    def _settle(self) -> None:
        """Let the body come to rest on its wheels (held) before time starts: the ground
        takes its weight, so the robot starts still and the IMU reads gravity."""
        if self.tyres.varies:
            self.tyres.update_friction()
        for _ in range(round(SETTLE_S / self.dt)):
            self._mujoco.mj_step(self.model, self.data)
            if float(np.abs(self.data.qvel).max()) < SLEEP_SPEED / 10:
                break
        self.wheels.take_positions()
        if not self.lifted:
            self._last_xy = self._xy()
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
        wheels = self.wheels
        if self.asleep:
            if wheels.driven():
                self._wake()
            else:
                self.cycle = cycle1
                wheels.follow_at_rest(cycle0, cycle1)
                return
        if cycle1 - cycle0 != self.step_cycles:
            raise ValueError(f"an awake physics body steps {self.step_cycles} cycles at a "
                             f"time, not {cycle1 - cycle0}")
        powered = wheels.apply_torques()
        steps = self.steps
        if not steps % FIELD_PERIOD_STEPS:
            if self.tyres.varies:
                self.tyres.update_friction()
            if not self.lifted:
                self._track_distance()
        self._mujoco.mj_step(self.model, self.data)
        self.steps = steps + 1
        self.cycle = cycle1
        if not steps % IMU_PERIOD_STEPS:
            self.imu.sample(self.data.sensordata)
        wheels.follow(cycle0, cycle1)
        if not powered and wheels.all_held:
            self._maybe_sleep()

    def _track_distance(self) -> None:
        x, y = self._xy()
        self.distance += math.hypot(x - self._last_xy[0], y - self._last_xy[1])
        self._last_xy = (x, y)

    def _maybe_sleep(self) -> None:
        if float(np.abs(self.data.qvel).max()) < SLEEP_SPEED:
            self._fall_asleep()

    def _fall_asleep(self) -> None:
        """Every wheel held and the body still: nothing moves until a wheel is driven."""
        self.data.qvel[:] = 0.0
        self.asleep = True
        self.wheels.rest()

    def _wake(self) -> None:
        self.asleep = False
        self.wheels.wake()

    def _stall_changed(self, drive: WheelDrive) -> None:
        """A blocked wheel (``WheelDrive.stall``, the ``wheel-stuck`` fault): its joint held
        where it is by an equality constraint until released."""
        self.wheels.hold_stalled(drive)
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
        mean = self.imu.mean()
        if mean is None and self.asleep:
            # Still: no rotation, and the accelerometer feels only the ground holding the
            # body up against gravity: g along the world's z, in the IMU's frame.
            rotation = np.empty(9)
            self._mujoco.mju_quat2Mat(rotation, self._orientation())
            mean = np.concatenate([np.zeros(3), STANDARD_GRAVITY * rotation[6:9]])
        elif mean is None:
            mean = np.array(self.data.sensordata[:6])
        q = self._orientation()
        return self.imu.read(self.t, mean, (float(q[0]), float(q[1]), float(q[2]),
                                            float(q[3])))

    def _orientation(self) -> np.ndarray[Any, Any]:
        """base_link's orientation (w, x, y, z) in the world."""
        if self.lifted:
            return np.array(_LEVEL)
        orientation: np.ndarray[Any, Any] = self.data.qpos[3:7]
        return orientation

    def wheel_speeds(self) -> dict[str, float]:
        """Each wheel's true speed (deg/s, physical sign)."""
        return {w.name: speed for w, speed in zip(self.description.wheels,
                                                  self.wheels.wheel_speeds(), strict=True)}

    def contact_forces(self) -> dict[str, float]:
        """The ground's normal force on each wheel (N), summed over its contacts."""
        return self.tyres.normal_forces()


def _yaw(q: Any) -> float:
    w, x, y, z = (float(v) for v in q)
    return wrap_angle(math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def _euler(q: Any) -> tuple[float, float, float]:
    w, x, y, z = (float(v) for v in q)
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, wrap_angle(yaw)
