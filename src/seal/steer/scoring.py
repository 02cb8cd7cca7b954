"""The value seam (V-GPS): a scorer rates sampled action chunks for a goal text.

``score(obs, chunks, goal) -> (K,) array``, higher is better. The paper's baseline uses an
IQL-trained Q-function conditioned on the task instruction (or, adapted to reasoning VLAs, on
the current sub-plan); SEAL's `value` method re-ranks K chunks with it at every step.
``make_scorer(name, checkpoint)`` loads one by name (``value``: `seal.value.vgps.VGPSScorer`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np

from seal.checkpoint import identity
from seal.registry import Registry
from seal.sim.observation import Observation
from seal.value import VALUE_FILES, VALUE_KIND, value_directory


class ChunkScorer(Protocol):
    needs_images: bool  # whether observations passed to ``score`` must carry camera images
    image_size: int  # the agent view's side it scores (224: openpi's view; a policy's own size, e.g. 64)

    def score(self, obs: Observation, chunks: np.ndarray, goal: str) -> np.ndarray:
        """``chunks`` is (K, horizon, 7); returns K scores, higher is better."""
        ...


# factory(checkpoint path) -> ChunkScorer
SCORERS = Registry("scorer", {"value": "seal.value.vgps:VGPSScorer.load"})


def make_scorer(name: str, checkpoint: str) -> ChunkScorer:
    return SCORERS.make(name, checkpoint)


def value_digest(path: str | Path) -> str:
    """What names a value checkpoint in a results store: sha1 of its verified weights and config."""
    return identity(value_directory(path), kind=VALUE_KIND, required=VALUE_FILES, files=VALUE_FILES,
                    algorithm="sha1")
