"""The package's own camera path, driven the way openpi's LIBERO example drives it.

This is the reference SEAL's observations are held to (``tests/test_pixels.py``, ``seal bench
sim``): ``OffScreenRenderEnv`` at 256 px, ``env.seed(7)``, one hard ``env.reset()`` per episode
so far, ``set_init_state``, 10 settle steps with the gripper open, then each frame turned by 180
degrees and pad-resized to 224 with openpi-client's ``resize_with_pad``. It builds a second,
slow env (robosuite renders both cameras at every step), so it is for checks, never for steering.
"""

from __future__ import annotations

from seal.sim import gl  # noqa: F401  (sets MUJOCO_GL before mujoco loads)

import contextlib
import io
from dataclasses import dataclass

import numpy as np
from openpi_client import image_tools

from seal.sim import background
from seal.sim.layout import OPENPI_SEED
from seal.sim.observation import AGENT_CAMERA, IMAGE_SIZE, RENDER_SIZE, quat_xyzw_to_axis_angle
from seal.sim.suites import TaskSpec

SETTLE_STEPS = 10
_DUMMY_ACTION = [0.0] * 6 + [-1.0]


@dataclass
class PackageFrame:
    agent: np.ndarray  # (224, 224, 3) uint8, as an openpi LIBERO server receives it
    wrist: np.ndarray
    state: np.ndarray  # (8,) openpi's state from the package's observation dict


def _openpi_image(frame: np.ndarray) -> np.ndarray:
    upright = np.ascontiguousarray(frame[::-1, ::-1])  # openpi's own line: robosuite rows come bottom-up
    return image_tools.convert_to_uint8(image_tools.resize_with_pad(upright, IMAGE_SIZE, IMAGE_SIZE))


def _frame(obs: dict) -> PackageFrame:
    state = np.concatenate([obs["robot0_eef_pos"], quat_xyzw_to_axis_angle(obs["robot0_eef_quat"]),
                            obs["robot0_gripper_qpos"]])
    return PackageFrame(_openpi_image(obs["agentview_image"]), _openpi_image(obs["robot0_eye_in_hand_image"]), state)


def package_frames(task: TaskSpec, episode: int, actions=(), *, camera_pose=None) -> list[PackageFrame]:
    """Frames of episode ``episode`` of ``task`` through the package: after the settle steps,
    then after each of ``actions``. ``camera_pose`` (pos, quat) moves the agent camera, as a
    visual-viewpoint world does (``LiberoWorld.camera_pose``)."""
    with contextlib.redirect_stdout(io.StringIO()):
        from libero.libero.envs import OffScreenRenderEnv

    room = background.scene_kwargs(task.room, task.background) if task.background else {}
    env = OffScreenRenderEnv(bddl_file_name=str(task.bddl_path), camera_heights=RENDER_SIZE,
                             camera_widths=RENDER_SIZE, **room)
    saved = np.random.get_state()  # env.seed() seeds numpy's global RNG; give the caller's back
    try:
        env.seed(OPENPI_SEED)
        for _ in range(episode + 1):
            env.reset()
        if camera_pose is not None:
            model = env.sim.model
            cam = model.camera_name2id(AGENT_CAMERA)
            model.cam_pos[cam], model.cam_quat[cam] = camera_pose
        obs = env.set_init_state(task.init_states()[episode])
        for _ in range(SETTLE_STEPS):
            obs, *_ = env.step(_DUMMY_ACTION)
        frames = [_frame(obs)]
        for action in actions:
            obs, *_ = env.step(np.asarray(action, dtype=np.float64))
            frames.append(_frame(obs))
        return frames
    finally:
        np.random.set_state(saved)
        env.close()
