"""The value seam (V-GPS): a scorer rates sampled action chunks for a goal text.

``score(obs, chunks, goal) -> (K,) array``, higher is better. The paper's baseline uses an
IQL-trained Q-function conditioned on the task instruction (or, adapted to reasoning VLAs, on
the current sub-plan); SEAL's `value` method re-ranks K chunks with it at every step.
``make_scorer(name, checkpoint)`` loads one by name (``value``: `seal.value.vgps.VGPSScorer`);
each entry carries its options class (`ValueOptions`: the checkpoint, digested into the config
hash). What a scorer looks at is `scoring_images` / `scoring_view`: the steering loop renders it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, ClassVar, Protocol

import numpy as np

from seal.options import Options, option
from seal.registry import Plugin, Registry
from seal.sim.observation import IMAGE_SIZE, Observation
from seal.value import VALUE_CHECKPOINT, value_directory


class ChunkScorer(Protocol):
    needs_images: bool  # whether observations passed to ``score`` must carry camera images
    image_size: int  # the agent view's side it scores (224: openpi's view; a policy's own size, e.g. 64)

    def score(self, obs: Observation, chunks: np.ndarray, goal: str) -> np.ndarray:
        """``chunks`` is (K, horizon, 7); returns K scores, higher is better."""
        ...


@dataclass(frozen=True)
class ValueOptions(Options):
    """A V-GPS checkpoint: the weights, not the path, decide the results (retraining in place is a
    new method)."""

    checkpoint: ClassVar[str] = "value_ckpt"
    value_ckpt: str = option("", "value: a `seal train value` run directory or a shipped name "
                                 "(default: the shipped Q-function)")

    def weights(self):
        return VALUE_CHECKPOINT, value_directory(self.value_ckpt)


# factory(checkpoint path) -> ChunkScorer
SCORERS = Registry("scorer", {
    "value": Plugin("seal.value.vgps:VGPSScorer.load", ValueOptions, "V-GPS: an IQL Q-function (`seal train value`)"),
})


def make_scorer(name: str, checkpoint: str) -> ChunkScorer:
    return SCORERS.make(name, checkpoint)


# ---- what a scorer looks at (the loop renders it) --------------------------------------------------
def scoring_images(scorer: ChunkScorer) -> bool | int:
    """The ``images`` argument of a pool call that renders what ``scorer`` looks at (False: nothing)."""
    if not scorer.needs_images:
        return False
    size = getattr(scorer, "image_size", IMAGE_SIZE)
    return True if size == IMAGE_SIZE else size


def scoring_view(scorer: ChunkScorer, obs: Observation, render: Callable[[bool | int], np.ndarray],
                 agent: np.ndarray | None = None) -> Observation:
    """What the Q-function scores: the agent view at the size it was trained on. When the policy
    reads its cameras at that size (a VLA and a value function both from 64-px data) its own
    renders serve; otherwise ``agent`` when it has that size, else one more render of the same
    state (``render(images)`` -> agent view)."""
    size = getattr(scorer, "image_size", IMAGE_SIZE)
    if not scorer.needs_images or (obs.agent is not None and obs.agent.shape[0] == size):
        return obs
    if agent is None or agent.shape[0] != size:
        agent = render(scoring_images(scorer))
    return Observation(state=obs.state, prompt=obs.prompt, agent=agent)
