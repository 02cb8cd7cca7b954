"""The value seam (V-GPS): a scorer rates sampled action chunks for a goal text.

``score(obs, chunks, goal) -> (K,) array``, higher is better. The paper's baseline uses an
IQL-trained Q-function conditioned on the task instruction (or, adapted to reasoning VLAs, on
the current sub-plan); SEAL's `value` method re-ranks K chunks with it at every step.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from seal.sim.observation import Observation


class ChunkScorer(Protocol):
    needs_images: bool  # whether observations passed to ``score`` must carry camera images

    def score(self, obs: Observation, chunks: np.ndarray, goal: str) -> np.ndarray:
        """``chunks`` is (K, horizon, 7); returns K scores, higher is better."""
        ...
