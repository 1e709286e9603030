"""The wheels' drives on the body: each :class:`fpgaemu.motor.WheelDrive`'s torque on its
motor's rotor, the wheel's motion back to the drive after each step, and the worm gears.

An unpowered wheel slower than :data:`HOLD_BAND_DPS` is held by its worm gear, which
self-locks: the worm wheel cannot turn the worm. The lock is at the mesh, on the wheel's
axle, so it is friction on the wheel's joint against the chassis (up to :data:`HOLD_SHARE`
of the stall torque), not on the rotor: the gearbox's compliance sits between the rotor and
the worm, and a wheel held only through it rang on it (a robot disabled at 0.2 m/s rocked
±2 cm/s for 1.5 s). A stalled wheel (the ``wheel-stuck`` fault) is held where it is by an
equality constraint until released."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from fpgaemu.motor import MAX_DUTY, DriveTrain, WheelDrive

__all__ = ["HOLD_BAND_DPS", "HOLD_SHARE", "DriveCoupling", "worm_hold_nm"]

#: An unpowered wheel turning slower than this is held by its worm gear (deg/s): above it the
#: rotor's own momentum still drives the worm forward, which a worm gear passes.
HOLD_BAND_DPS = 10.0
#: The holding torque of an unpowered worm gear at the wheel's axle (friction on the wheel's
#: joint), as a share of the motor's stall torque: far above any load the ground puts on a
#: wheel of this robot (20 N·m each on the 45° slope), so the tyres slide before it yields.
HOLD_SHARE = 0.5
_DEGREES = 180.0 / math.pi


def worm_hold_nm(train: DriveTrain) -> float:
    """The holding torque (N·m) of an unpowered worm gear of ``train`` at its wheel's axle."""
    return HOLD_SHARE * train.stall_torque_nm


class DriveCoupling:
    """The drives of ``wheels`` (in that order) coupled to their joints in the model: the
    wheel's joint is named after the wheel, its rotor's ``NAME_rotor``, the constraint that
    blocks it ``NAME_blocked`` (:func:`fpgaemu.physics.model.mjcf`)."""

    def __init__(self, model: Any, data: Any, wheels: list[str], drives: list[WheelDrive],
                 dt: float) -> None:
        self.drives = drives
        self._model = model
        self._data = data
        self._dt = dt
        self._wheel_q = [int(model.joint(n).qposadr[0]) for n in wheels]
        rotor_q = [int(model.joint(f"{n}_rotor").qposadr[0]) for n in wheels]
        self._wheel_dof = [int(model.joint(n).dofadr[0]) for n in wheels]
        self._blocked = [int(model.equality(f"{n}_blocked").id) for n in wheels]
        #: the wheels' angles, then the rotors', in one gather from qpos
        self._gather = np.array([*self._wheel_q, *rotor_q])
        train = drives[0].train
        self._hold = worm_hold_nm(train)
        motor = train.motor
        tau = motor.inductance_h / motor.resistance_ohm
        #: for the drives' torque over a step (WheelDrive.torque_over, written out)
        self._electrics = (motor.supply_v, motor.resistance_ohm, train.torque_constant,
                           tau / dt * (1.0 - math.exp(-dt / tau)))
        self._held = [True] * len(wheels)
        self._stalled = [False] * len(wheels)
        self._angles: list[float] = []
        self._rotors: list[float] = []
        self.take_positions()

    def take_positions(self) -> None:
        """The wheels' and rotors' angles now: where the next step's motion starts."""
        angles = self._data.qpos[self._gather].tolist()
        n = len(self.drives)
        self._angles, self._rotors = angles[:n], angles[n:]

    @property
    def all_held(self) -> bool:
        """Every wheel held by its worm gear (or its stall)."""
        return all(self._held)

    def driven(self) -> bool:
        """Whether any drive has a duty or a current (the body must move)."""
        return any(drive.duty or drive.current for drive in self.drives)

    def apply_torques(self) -> bool:
        """The drives' torques over the next step on their rotors and the worm gears' holds
        on the unpowered wheels; whether any drive is powered."""
        # WheelDrive.torque_over and the holds, written out: this runs every physics step.
        model = self._model
        held, stalled = self._held, self._stalled
        supply, resistance, k, share = self._electrics
        torques = []
        powered = False
        for i, drive in enumerate(self.drives):
            duty = drive.duty
            if duty:
                powered = True
            hold = not duty and -HOLD_BAND_DPS < drive.wheel_speed_dps < HOLD_BAND_DPS
            if hold != held[i] and not stalled[i]:
                held[i] = hold
                model.dof_frictionloss[self._wheel_dof[i]] = self._hold if hold else 0.0
            steady = (supply * duty / MAX_DUTY - k * drive.rotor_speed) / resistance
            torques.append(k * (steady + (drive.current - steady) * share))
        self._data.ctrl[:] = torques
        return powered

    def follow(self, cycle0: int, cycle1: int) -> None:
        """After a step from ``cycle0`` to ``cycle1``: each drive follows its wheel."""
        drives, dt = self.drives, self._dt
        positions = self._data.qpos[self._gather].tolist()
        n = len(drives)
        wheels, rotors = positions[:n], positions[n:]
        angles, last_rotors = self._angles, self._rotors
        to_degrees = _DEGREES
        for i, drive in enumerate(drives):
            drive.follow_physics(cycle0, cycle1, wheels[i] * to_degrees,
                                 (wheels[i] - angles[i]) * to_degrees / dt,
                                 (rotors[i] - last_rotors[i]) / dt)
        self._angles, self._rotors = wheels, rotors

    def follow_at_rest(self, cycle0: int, cycle1: int) -> None:
        """The body asleep from ``cycle0`` to ``cycle1``: every wheel stands where it is."""
        for drive, angle in zip(self.drives, self._angles, strict=True):
            drive.follow_physics(cycle0, cycle1, math.degrees(angle), 0.0, 0.0)

    def rest(self) -> None:
        """The body fell asleep: every drive's wheel and rotor stand still."""
        for drive in self.drives:
            drive.rotor_speed = 0.0
            drive.wheel_speed_dps = 0.0
            drive.body_asleep = True

    def wake(self) -> None:
        for drive in self.drives:
            drive.body_asleep = False

    def hold_stalled(self, drive: WheelDrive) -> None:
        """``drive``'s wheel blocked where it is while it is stalled, released after."""
        i = self.drives.index(drive)
        self._stalled[i] = drive.stalled
        blocked = self._blocked[i]
        if drive.stalled:
            self._model.eq_data[blocked, 0] = self._data.qpos[self._wheel_q[i]]
        self._data.eq_active[blocked] = 1 if drive.stalled else 0

    def wheel_speeds(self) -> list[float]:
        """Each wheel's true speed (deg/s, physical sign), in the wheels' order."""
        v = self._data.qvel
        return [math.degrees(float(v[d])) for d in self._wheel_dof]
