"""What the V-GPS value function sees of a step, the same in training and at run time: the agent
view at `IMAGE_SIDE` px (`downsample`) and the executed chunk (`chunk_of`).

`seal.train.transitions` builds its training rows with these, `seal.value.vgps.VGPSScorer` its
inputs while steering; no PyTorch is needed here.
"""

from __future__ import annotations

import numpy as np

from seal.errors import InvalidInput
from seal.policies.base import ACTION_HORIZON

IMAGE_SIDE = 56  # 224 / 4: small enough for CPU training, big enough to see which object moved


def downsample(images: np.ndarray) -> np.ndarray:
    """(..., S, S, 3) uint8 -> (..., 56, 56, 3) uint8, the value function's input.

    From openpi's 224-px view: 4x4 mean pooling. From a policy-sized view (a VLA recorded at 64 px):
    an area (box-filter) resize, so the value function trains and scores on what the policy sees."""
    *lead, h, w, c = images.shape
    if h != w:
        raise InvalidInput(f"expected square images, got {h}x{w}")
    if h % IMAGE_SIDE == 0:
        f = h // IMAGE_SIDE
        pooled = images.reshape(*lead, IMAGE_SIDE, f, IMAGE_SIDE, f, c).mean(axis=(-4, -2))
        return pooled.round().astype(np.uint8)
    from PIL import Image

    flat = images.reshape(-1, h, w, c)
    how = Image.BOX if h > IMAGE_SIDE else Image.BILINEAR  # area when shrinking; a smaller view is stretched
    out = np.stack([np.asarray(Image.fromarray(im).resize((IMAGE_SIDE, IMAGE_SIDE), how)) for im in flat])
    return out.reshape(*lead, IMAGE_SIDE, IMAGE_SIDE, c)


def chunk_of(actions: np.ndarray) -> np.ndarray:
    """The first ``ACTION_HORIZON`` actions of a chunk, padded with its last row, flattened."""
    a = np.asarray(actions, dtype=np.float32)[:ACTION_HORIZON]
    if len(a) < ACTION_HORIZON:
        a = np.concatenate([a, np.repeat(a[-1:], ACTION_HORIZON - len(a), axis=0)])
    return np.clip(a, -1.0, 1.0).reshape(-1)
