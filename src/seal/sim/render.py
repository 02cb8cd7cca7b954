"""Camera images of a world state, in the stock look or a fast low-polygon look.

A render here is a pure function of the physics state: the renderer keeps its own scratch
``MjData``, copies the positions into it and recomputes kinematics before drawing. So the
same state gives the same pixels after a snapshot restore or in another process, and the
fast mode can draw a different (decimated) model of the same scene without touching physics.
"""

from __future__ import annotations

from seal.sim import gl  # noqa: F401  (sets MUJOCO_GL before mujoco loads)

import mujoco
import numpy as np

RENDER_MODES = ("stock", "fast")


class SceneRenderer:
    """Draws ``camera`` views of a physics state through a render model of the same scene."""

    def __init__(self, render_model: mujoco.MjModel, size: int = 256):
        self.model = render_model
        self.size = size
        self._data = mujoco.MjData(render_model)
        self._renderer = mujoco.Renderer(render_model, height=size, width=size)
        gl.track(self)

    def render(self, physics_model: mujoco.MjModel, physics_data: mujoco.MjData, camera: str) -> np.ndarray:
        """An (size, size, 3) uint8 image as MuJoCo draws it (upside down for LIBERO cameras)."""
        self._sync(physics_model, physics_data)
        self._renderer.update_scene(self._data, camera=camera)
        return self._renderer.render()

    def render_many(self, physics_model, physics_data, cameras) -> dict[str, np.ndarray]:
        self._sync(physics_model, physics_data)
        out = {}
        for camera in cameras:
            self._renderer.update_scene(self._data, camera=camera)
            out[camera] = self._renderer.render()
        return out

    def _sync(self, physics_model: mujoco.MjModel, physics_data: mujoco.MjData) -> None:
        d = self._data
        d.qpos[:] = physics_data.qpos
        d.mocap_pos[:] = physics_data.mocap_pos
        d.mocap_quat[:] = physics_data.mocap_quat
        if self.model is not physics_model:
            # LIBERO toggles site alpha at run time (e.g. the stove's flame): mirror it.
            self.model.site_rgba[:] = physics_model.site_rgba
            self.model.geom_rgba[:] = physics_model.geom_rgba
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_camlight(self.model, d)

    def close(self) -> None:
        renderer, self._renderer = getattr(self, "_renderer", None), None
        if renderer is not None:
            renderer.close()
