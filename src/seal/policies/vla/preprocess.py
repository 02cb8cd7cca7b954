"""What training and inference both do to raw inputs, in one place so they cannot drift apart:
images to the model's resolution, texts to padded token ids.

Images: the model sees ``image_size`` square uint8 RGB frames in openpi's orientation (what
`seal.sim.observation` produces). Frames already at that size pass through untouched (the
simulator renders at 64 px directly, and demos can be recorded at 64 px). Any other size (a
224-px dataset, a remote client) is resized with PIL's BOX filter when shrinking: each output
pixel is the area average of the input pixels it covers, which is what a lower-resolution
camera would have seen and does not alias the way point sampling does; BILINEAR when growing.
"""

from __future__ import annotations

import numpy as np
from PIL import Image

from seal.errors import InvalidInput
from seal.policies.vla.tokenizer import VLATokenizer


def resize_images(images: np.ndarray, size: int) -> np.ndarray:
    """(..., H, W, 3) uint8 -> (..., size, size, 3) uint8 (a no-op at the right size)."""
    images = np.asarray(images)
    if images.dtype != np.uint8 or images.ndim < 3 or images.shape[-1] != 3:
        raise InvalidInput(f"images must be uint8 (..., H, W, 3), got {images.dtype} {images.shape}")
    h, w = images.shape[-3:-1]
    if (h, w) == (size, size):
        return images
    method = Image.Resampling.BOX if size <= min(h, w) else Image.Resampling.BILINEAR
    flat = images.reshape(-1, h, w, 3)
    out = np.stack([np.asarray(Image.fromarray(im).resize((size, size), method)) for im in flat])
    return out.reshape(*images.shape[:-3], size, size, 3)


def instruction_ids(tok: VLATokenizer, text: str, length: int) -> tuple[np.ndarray, np.ndarray]:
    """``<bos> instruction`` padded to ``length``; an instruction too long is cut (the prefix has a
    fixed size). Returns (ids int64, valid bool)."""
    ids = [tok.bos_id] + tok.encode(text.strip())[: length - 1]
    out = np.full(length, tok.pad_id, np.int64)
    out[: len(ids)] = ids
    return out, np.arange(length) < len(ids)


def reasoning_ids(tok: VLATokenizer, text: str, length: int, *, strict: bool = False
                  ) -> tuple[np.ndarray, np.ndarray, int]:
    """``<think> reasoning <act>`` padded to ``length``: (ids, valid, index of <act>).

    ``strict``: a text that does not fit raises (training data must fit: a cut label would teach
    the model to stop mid-sentence); otherwise it is cut and still closed with <act>."""
    body = tok.encode(text)
    if len(body) + 2 > length:
        if strict:
            raise InvalidInput(f"a reasoning label of {len(body) + 2} tokens does not fit max_reasoning_tokens="
                               f"{length}: raise it in the VLA config ({text[:80]!r}...)")
        body = body[: length - 2]
    ids = [tok.think_id, *body, tok.act_id]
    out = np.full(length, tok.pad_id, np.int64)
    out[: len(ids)] = ids
    return out, np.arange(length) < len(ids), len(ids) - 1
