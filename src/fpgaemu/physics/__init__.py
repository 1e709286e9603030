"""The robot's body on a physics engine (MuJoCo): a rigid chassis on four wheels whose
motors are the boards' own (:class:`fpgaemu.motor.WheelDrive`), on a ground of a chosen
surface — the body the kinematic one (:mod:`fpgaemu.body`) is not: the wheels slip, the
ground loads them, the body pitches and rolls, and an IMU feels it. One concern a module:

* :mod:`~fpgaemu.physics.surfaces` — the grounds (:data:`SURFACES`) and a patchy one's
  friction field;
* :mod:`~fpgaemu.physics.model` — the MuJoCo model (MJCF) generated from the robot
  description (:func:`mjcf`), and the physics step (:data:`STEP_CYCLES`);
* :mod:`~fpgaemu.physics.drives` — the wheels' drives on the body: torques on the rotors,
  the wheels' motion back, the worm gears' holds (:data:`HOLD_BAND_DPS`) and stalls;
* :mod:`~fpgaemu.physics.contact` — the tyres on the ground: friction re-read under each
  wheel (every :data:`FIELD_PERIOD_STEPS` steps) and the ground's load on each;
* :mod:`~fpgaemu.physics.imu` — the IMU (:class:`Imu`, :class:`ImuReading`);
* :mod:`~fpgaemu.physics.body` — :class:`PhysicsBody`: the model stepped, asleep when
  still, and read;
* :mod:`~fpgaemu.physics.render` — a picture of it (:func:`render`).

MuJoCo (the ``physics`` extra) is imported only when a body is made or rendered, so the
surfaces and :func:`why_unavailable` are there without it.
"""

from __future__ import annotations

from fpgaemu.physics.body import PhysicsBody
from fpgaemu.physics.contact import FIELD_PERIOD_STEPS
from fpgaemu.physics.drives import HOLD_BAND_DPS
from fpgaemu.physics.imu import Imu, ImuReading
from fpgaemu.physics.model import STEP_CYCLES, mjcf
from fpgaemu.physics.render import render
from fpgaemu.physics.surfaces import SURFACES, Surface

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


def why_unavailable() -> str | None:
    """Why the physics body cannot run here (``None`` when it can)."""
    try:
        import mujoco  # noqa: F401
    except ImportError as exc:
        return f"MuJoCo is not installed ({exc}); pip install 'fpgalink[physics]'"
    return None


def available() -> bool:
    return why_unavailable() is None
