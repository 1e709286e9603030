"""A picture of the physics body with MuJoCo's own renderer (docs/robot.md's figure)."""

from __future__ import annotations

from typing import Any

import numpy as np

from fpgaemu.physics.body import PhysicsBody

__all__ = ["render"]


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
