"""The tyres on the ground: each tyre's friction re-read under its wheel from the surface's
friction field (every :data:`FIELD_PERIOD_STEPS` steps), and the ground's load on each
wheel."""

from __future__ import annotations

from typing import Any

import numpy as np

from fpgaemu.physics.surfaces import FrictionField, Surface
from fpgalink.protocol.robot import WHEEL_NAMES

__all__ = ["FIELD_PERIOD_STEPS", "TyreContacts"]

#: The gravel's friction field is re-read under the wheels this often (20 ms: a wheel at full
#: speed moves 6 mm).
FIELD_PERIOD_STEPS = 10
#: A tyre's geom is named after its wheel: ``FL_tyre`` (:func:`fpgaemu.physics.model.mjcf`).
TYRE_SUFFIX = "_tyre"


class TyreContacts:
    """The model's contact pairs of tyre and ground, one per tyre and ground geom."""

    def __init__(self, mujoco: Any, model: Any, data: Any, wheels: list[str],
                 surface: Surface, seed: int) -> None:
        self._mujoco = mujoco
        self._model = model
        self._data = data
        self._field = FrictionField(seed, surface)
        self._wheel_bodies = np.array([int(model.body(f"{n}_link").id) for n in wheels])
        tyres = [next(n for g in pair if (n := model.geom(int(g)).name).endswith(TYRE_SUFFIX))
                 for pair in zip(model.pair_geom1, model.pair_geom2, strict=True)]
        #: the wheel (its index in ``wheels``) of each contact pair
        self._pair_wheel = np.array([wheels.index(t.removesuffix(TYRE_SUFFIX)) for t in tyres])
        self._base_friction = model.pair_friction[:, :2].copy()

    @property
    def varies(self) -> bool:
        """Whether the friction differs over the ground (a friction field)."""
        return self._field.active

    def update_friction(self) -> None:
        """Each pair's sliding friction: the surface's, scaled by the field under its wheel."""
        xy = self._data.xpos[self._wheel_bodies, :2]
        scale = self._field.scale(xy)[self._pair_wheel]
        self._model.pair_friction[:, :2] = self._base_friction * scale[:, None]

    def normal_forces(self) -> dict[str, float]:
        """The ground's normal force on each wheel (N), summed over its contacts."""
        out = dict.fromkeys(WHEEL_NAMES, 0.0)
        force = np.zeros(6)
        model, data = self._model, self._data
        for i in range(data.ncon):
            contact = data.contact[i]
            for geom in (contact.geom1, contact.geom2):
                name = model.geom(int(geom)).name
                if name.endswith(TYRE_SUFFIX):
                    self._mujoco.mj_contactForce(model, data, i, force)
                    out[name.removesuffix(TYRE_SUFFIX)] += float(force[0])
        return out
