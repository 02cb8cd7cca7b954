"""The value seam (V-GPS): a scorer rates sampled action chunks for a goal text.

``score(obs, chunks, goal) -> (K,) array``, higher is better. The paper's baseline uses an
IQL-trained Q-function conditioned on the task instruction (or, adapted to reasoning VLAs, on
the current sub-plan); SEAL's `value` method re-ranks K chunks with it at every step.
``make_scorer(name, checkpoint)`` loads one by name (``value``: `seal.train.vgps.VGPSScorer`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np

from seal.checkpoint import identity
from seal.errors import InvalidInput
from seal.registry import Registry
from seal.sim.observation import Observation

# A V-GPS checkpoint directory (`seal train value` writes one into its run directory): the
# networks' weights, what shapes them, and the manifest that vouches for both (`seal.checkpoint`).
VALUE_KIND = "seal-vgps"
VALUE_WEIGHTS, VALUE_CONFIG = "value.safetensors", "value.json"
VALUE_FILES = (VALUE_WEIGHTS, VALUE_CONFIG)


class ChunkScorer(Protocol):
    needs_images: bool  # whether observations passed to ``score`` must carry camera images
    image_size: int  # the agent view's side it scores (224: openpi's view; a policy's own size, e.g. 64)

    def score(self, obs: Observation, chunks: np.ndarray, goal: str) -> np.ndarray:
        """``chunks`` is (K, horizon, 7); returns K scores, higher is better."""
        ...


# factory(checkpoint path) -> ChunkScorer
SCORERS = Registry("scorer", {"value": "seal.train.vgps:VGPSScorer.load"})


def make_scorer(name: str, checkpoint: str) -> ChunkScorer:
    return SCORERS.make(name, checkpoint)


def value_directory(path: str | Path) -> Path:
    """A V-GPS checkpoint directory from a run directory or one of its files."""
    p = Path(path)
    p = p.parent if p.is_file() else p
    if not (p / VALUE_WEIGHTS).is_file() and not (p / "manifest.json").is_file():
        raise InvalidInput(f"no V-GPS checkpoint at {p} (no {VALUE_WEIGHTS}); train one with `seal train value`")
    return p


def value_digest(path: str | Path) -> str:
    """What names a value checkpoint in a results store: sha1 of its verified weights and config."""
    return identity(value_directory(path), kind=VALUE_KIND, required=VALUE_FILES, files=VALUE_FILES,
                    algorithm="sha1")
