"""Demonstrations -> chunk-level offline-RL transitions for the V-GPS value function.

One transition per executed chunk (5 actions, the chunk a policy runs before it is asked
again): the agent view before the chunk (downsampled), the 8-d state, the chunk, a goal text,
a reward, whether the goal was reached, and the same observation after the chunk.

Two kinds of goal come out of one episode, so one Q-function can score both ways the steering
engine asks (``value_goal``): the task instruction (V-GPS as published; reward when the episode
ends in success) and each sub-plan text (the reasoning-VLA adaptation; reward on the chunk where
that sub-goal first held, known from the recorded critical frames). Rewards are sparse: 1 on the
chunk that reaches the goal (which ends the transition chain), 0 elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.datasets import Episode
from seal.errors import InvalidInput
from seal.policies.base import ACTION_HORIZON
from seal.value.inputs import IMAGE_SIDE, chunk_of, downsample

GOAL_KINDS = ("task", "subplan", "both")


@dataclass
class Transitions:
    """Column arrays, one row per (chunk, goal)."""

    image: np.ndarray       # (N, 56, 56, 3) uint8, agent view before the chunk
    state: np.ndarray       # (N, 8) float32
    action: np.ndarray      # (N, 35) float32
    goal: list[str]         # (N,)
    reward: np.ndarray      # (N,) float32
    done: np.ndarray        # (N,) float32: the goal was reached by this chunk
    next_image: np.ndarray  # (N, 56, 56, 3) uint8
    next_state: np.ndarray  # (N, 8) float32
    to_goal: np.ndarray     # (N,) int32: chunks until the goal is reached counting this one (1 = this
                            # chunk reaches it), -1 if never; for Monte-Carlo checks of a learned value

    def __len__(self) -> int:
        return len(self.reward)

    @staticmethod
    def concat(parts: list[Transitions]) -> Transitions:
        if not parts:
            raise InvalidInput("no transitions: the dataset has no episodes long enough for one chunk")
        return Transitions(*(np.concatenate([getattr(p, f) for p in parts]) if f != "goal"
                             else [g for p in parts for g in p.goal]
                             for f in Transitions.__dataclass_fields__))


def _windows(ep: Episode, goals: str) -> list[tuple[str, int, int, bool]]:
    """(goal text, first step, last step, reached) per goal; steps index actions."""
    T = ep.length
    out = []
    if goals in ("task", "both"):
        out.append((ep.instruction, 0, T - 1, bool(ep.meta.get("success", True))))
    if goals in ("subplan", "both"):
        start = 0
        for text, frame in zip(ep.subplans, ep.critical_frames):
            # frame f is observed after action f-1: that action reached the sub-goal
            reached = frame > 0
            end = frame - 1 if reached else T - 1
            if end >= start:
                out.append((text, start, end, reached))
            if not reached:
                break  # later sub-plans never started properly
            start = end + 1
    return out


def episode_transitions(ep: Episode, goals: str = "both", small: np.ndarray | None = None) -> Transitions:
    """Chunk transitions of one episode; ``small`` is its downsampled agent view if already made."""
    if goals not in GOAL_KINDS:
        raise InvalidInput(f"unknown goal kind {goals!r}; valid: {', '.join(GOAL_KINDS)}")
    small = downsample(ep.agent_images) if small is None else small
    states = np.asarray(ep.states, dtype=np.float32)
    rows: dict[str, list] = {f: [] for f in Transitions.__dataclass_fields__}
    for text, first, last, reached in _windows(ep, goals):
        starts = range(first, last + 1, ACTION_HORIZON)
        for j, s in enumerate(starts):
            e = min(s + ACTION_HORIZON, last + 1)  # the chunk never runs past its goal's window
            hit = reached and e == last + 1
            nxt = min(e, ep.length - 1)
            rows["image"].append(small[s])
            rows["state"].append(states[s])
            rows["action"].append(chunk_of(ep.actions[s:e]))
            rows["goal"].append(text)
            rows["reward"].append(float(hit))
            rows["done"].append(float(hit))
            rows["next_image"].append(small[nxt])
            rows["next_state"].append(states[nxt])
            rows["to_goal"].append(len(starts) - j if reached else -1)
    if not rows["reward"]:
        return Transitions(np.zeros((0, IMAGE_SIDE, IMAGE_SIDE, 3), np.uint8), np.zeros((0, 8), np.float32),
                           np.zeros((0, 7 * ACTION_HORIZON), np.float32), [], np.zeros(0, np.float32),
                           np.zeros(0, np.float32), np.zeros((0, IMAGE_SIDE, IMAGE_SIDE, 3), np.uint8),
                           np.zeros((0, 8), np.float32), np.zeros(0, np.int32))
    dtypes = {"image": np.uint8, "next_image": np.uint8, "to_goal": np.int32}
    return Transitions(**{f: (v if f == "goal" else np.asarray(v, dtype=dtypes.get(f, np.float32)))
                          for f, v in rows.items()})


def load_transitions(root, goals: str = "both", episodes: list[int] | None = None,
                     progress=None) -> Transitions:
    """Transitions of a LeRobot dataset's episodes (default: all), decoding the agent view only once."""
    from seal.datasets import open_dataset

    reader = open_dataset(root)
    episodes = list(range(reader.num_episodes)) if episodes is None else episodes
    parts = []
    for n, i in enumerate(episodes):
        ep = reader.episode(i)
        parts.append(episode_transitions(ep, goals))
        if progress:
            progress(n + 1, len(episodes))
    return Transitions.concat(parts)
