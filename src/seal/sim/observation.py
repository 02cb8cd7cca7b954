"""Observations in openpi's LIBERO convention, so real pi0 servers plug in unchanged.

- images: rendered at 256, mirrored left-right, resized with zero padding to 224 using
  openpi-client's own ``resize_with_pad``. Why a mirror: robosuite's offscreen camera hands
  out rows bottom-up and openpi turns those frames by 180 degrees (``[::-1, ::-1]``), which puts
  them upright but mirrored. ``mujoco.Renderer`` already returns upright rows, so the same
  pixels need only the column flip. (Turning an upright render by 180 degrees, as this module
  once did, shows the robot upside down at the bottom of the frame.) Scene visibility matches
  robosuite's too (``seal.sim.render``); ``tests/test_pixels.py`` holds both to the package;
- state (8): end-effector position (3), axis-angle of the end-effector quaternion (3),
  gripper finger joint positions (2);
- prompt: the task's language instruction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from openpi_client import image_tools

from seal.sim.scene import SceneState

IMAGE_SIZE = 224
RENDER_SIZE = 256
AGENT_CAMERA = "agentview"
WRIST_CAMERA = "robot0_eye_in_hand"


@dataclass
class Observation:
    state: np.ndarray  # (8,) float64
    prompt: str
    agent: np.ndarray | None = None  # (224, 224, 3) uint8, None when not rendered
    wrist: np.ndarray | None = None
    scene: "SceneState | None" = None  # privileged; only scripted policies ask for it

    def to_openpi(self) -> dict:
        """The request dict an openpi LIBERO policy server expects."""
        if self.agent is None or self.wrist is None:
            raise ValueError("this observation was taken without images; observe(images=True) first")
        return {
            "observation/image": self.agent,
            "observation/wrist_image": self.wrist,
            "observation/state": self.state.astype(np.float32),
            "prompt": self.prompt,
        }


def quat_xyzw_to_axis_angle(quat: np.ndarray) -> np.ndarray:
    """Axis-angle (3) of an (x, y, z, w) quaternion, the formula openpi's LIBERO example uses."""
    w = min(max(float(quat[3]), -1.0), 1.0)
    den = math.sqrt(1.0 - w * w)
    if math.isclose(den, 0.0):
        return np.zeros(3)
    return np.asarray(quat[:3], dtype=np.float64) * 2.0 * math.acos(w) / den


def mirror(raw: np.ndarray) -> np.ndarray:
    """An upright render in openpi's orientation (a left-right mirror; see the module docstring)."""
    return np.ascontiguousarray(raw[:, ::-1])


def to_policy_image(raw: np.ndarray, size: int = IMAGE_SIZE) -> np.ndarray:
    """An upright render -> the policy's view: mirror left-right as openpi's frames are, pad-resize to ``size``."""
    return image_tools.convert_to_uint8(image_tools.resize_with_pad(mirror(raw), size, size))
