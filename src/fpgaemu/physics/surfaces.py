"""The grounds the physics body knows (:data:`SURFACES`), calibrated against the seed's §3.6
runs (docs/robot.md), and the friction field of a patchy one (:class:`FrictionField`):
gravel's coefficient varies smoothly over the ground, so the centre of an in-place turn
wanders as in §3.6.3. ``slope45-sand`` tilts the ground by 45° (the robot faces uphill);
``stairs`` puts three 40° steps (0.17 m rise, 0.20 m run) ahead of the robot, going down."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["SURFACES", "FrictionField", "Surface"]


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


class FrictionField:
    """A smooth random field over the ground, seeded: the friction coefficient under a
    point is the surface's times 1 + spread·g(x, y), g a unit-variance Gaussian field with
    the surface's correlation length (random Fourier features), clipped to 0.3–1.7."""

    FEATURES = 48

    def __init__(self, seed: int, surface: Surface) -> None:
        #: whether the friction varies at all (a uniform ground has no field)
        self.active = surface.field_spread > 0.0
        rng = np.random.default_rng([seed, 0xF1E1D])
        self._k = rng.normal(0.0, 1.0 / surface.field_length, (2, self.FEATURES))
        self._phase = rng.uniform(0.0, math.tau, self.FEATURES)
        self._amplitude = math.sqrt(2.0 / self.FEATURES) * surface.field_spread

    def scale(self, xy: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
        """The factor on the surface's friction under each point of ``xy`` (n × 2, m)."""
        g = np.cos(xy @ self._k + self._phase).sum(axis=1) * self._amplitude
        result: np.ndarray[Any, Any] = np.clip(1.0 + g, 0.3, 1.7)
        return result
