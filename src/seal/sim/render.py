"""Camera images of a world state, in the stock look or a fast low-polygon look.

A render here is a pure function of the physics state: the renderer keeps its own scratch
``MjData``, copies the positions into it and recomputes kinematics before drawing. So the
same state gives the same pixels after a snapshot restore or in another process, and the
fast mode can draw a different (decimated) model of the same scene without touching physics.

What is drawn matches robosuite's offscreen camera, which LIBERO's and openpi's images come
from: collision geoms (group 0) hidden, visual meshes (group 1) and sites' default groups shown.
``mujoco.Renderer``'s default scene option would draw group 0 too, painting the collision hulls
over the visual meshes. Unlike robosuite's context, ``mujoco.Renderer.render()`` returns rows
top-down, i.e. an upright image; see ``seal.sim.observation`` for how that maps onto openpi's frames.
"""

from __future__ import annotations

from seal.sim import gl  # noqa: F401  (sets MUJOCO_GL before mujoco loads)

import mujoco
import numpy as np

RENDER_MODES = ("stock", "fast")
# Geom groups robosuite's offscreen renderer shows by default (``vopt.geomgroup[0] = 0``,
# unless an env asks for collision meshes): MuJoCo's default option shows 0-2.
VISIBLE_GEOM_GROUPS = (1, 2)


def scene_option() -> mujoco.MjvOption:
    """The visibility options of a stock LIBERO camera image."""
    option = mujoco.MjvOption()
    for group in range(len(option.geomgroup)):
        option.geomgroup[group] = int(group in VISIBLE_GEOM_GROUPS)
    return option


def drawn_faces(model: mujoco.MjModel) -> int:
    """Mesh faces a stock camera draws per frame (each visible mesh geom counts; a mesh drawn by
    two geoms counts twice): what the render time scales with, unlike ``mesh_facenum.sum()``,
    which also counts collision meshes nobody draws."""
    geoms = np.flatnonzero((model.geom_type == mujoco.mjtGeom.mjGEOM_MESH) & (model.geom_rgba[:, 3] > 0)
                           & np.isin(model.geom_group, VISIBLE_GEOM_GROUPS))
    return int(model.mesh_facenum[model.geom_dataid[geoms]].sum())


class SceneRenderer:
    """Draws ``camera`` views of a physics state through a render model of the same scene."""

    def __init__(self, render_model: mujoco.MjModel, size: int = 256, option: mujoco.MjvOption | None = None):
        self.model = render_model
        self.size = size
        self._data = mujoco.MjData(render_model)
        self._renderer = mujoco.Renderer(render_model, height=size, width=size)
        self._option = scene_option() if option is None else option
        gl.track(self)

    def render(self, physics_model: mujoco.MjModel, physics_data: mujoco.MjData, camera: str,
               qpos: np.ndarray | None = None) -> np.ndarray:
        """An upright (size, size, 3) uint8 image of ``camera``, at ``qpos`` if given (else the data's)."""
        return self.render_many(physics_model, physics_data, (camera,), qpos)[camera]

    def render_many(self, physics_model, physics_data, cameras, qpos=None) -> dict[str, np.ndarray]:
        self._sync(physics_model, physics_data, qpos)
        out = {}
        for camera in cameras:
            self._renderer.update_scene(self._data, camera=camera, scene_option=self._option)
            out[camera] = self._renderer.render()
        return out

    def _sync(self, physics_model: mujoco.MjModel, physics_data: mujoco.MjData, qpos=None) -> None:
        d = self._data
        d.qpos[:] = physics_data.qpos if qpos is None else qpos
        d.mocap_pos[:] = physics_data.mocap_pos
        d.mocap_quat[:] = physics_data.mocap_quat
        if self.model is not physics_model:
            # LIBERO toggles site alpha at run time (e.g. the stove's flame) and places fixtures
            # by moving their bodies in the model (``seal.sim.layout``): mirror both.
            self.model.site_rgba[:] = physics_model.site_rgba
            self.model.geom_rgba[:] = physics_model.geom_rgba
            self.model.body_pos[:] = physics_model.body_pos
            self.model.body_quat[:] = physics_model.body_quat
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_camlight(self.model, d)

    def close(self) -> None:
        renderer, self._renderer = getattr(self, "_renderer", None), None
        if renderer is not None:
            # mujoco's Renderer.close() frees its MjrContext in whichever GL context is current;
            # with several renderers in a process (a world per render mode, a new size) that is
            # another renderer's, whose buffers and textures then vanish and whose renders come
            # back stale. Make ours current first.
            context = getattr(renderer, "_gl_context", None)
            if context is not None:
                context.make_current()
            renderer.close()
