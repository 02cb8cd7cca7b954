"""Demonstrations -> chunk-level offline-RL transitions for the V-GPS value function.

One transition per executed chunk (5 actions, the chunk a policy runs before it is asked
again): the agent view before the chunk (downsampled), the 8-d state, the chunk, a goal text,
a reward, whether the goal was reached, and the same observation after the chunk.

Two kinds of goal come out of one episode, so one Q-function can score both ways the steering
engine asks (``value_goal``): the task instruction (V-GPS as published; reward when the episode
ends in success) and each sub-plan text (the reasoning-VLA adaptation; reward on the chunk where
that sub-goal first held, known from the recorded critical frames). Rewards are sparse: 1 on the
chunk that reaches the goal (which ends the transition chain), 0 elsewhere.

Demonstrations only ever succeed, so a Q-function trained on them alone has never seen a chunk that
fails and rates unseen chunks arbitrarily; re-ranking a policy's samples by it then picks what it
knows least. `rollout_transitions` adds a policy's own rollouts (`seal demos dagger` collections,
whose frames are chunk boundaries and which keep the executed actions): failures included, with the
sub-goals read from the scripted expert's label at every boundary.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.datasets import Episode
from seal.errors import InvalidInput
from seal.policies.base import ACTION_HORIZON, parse_reasoning
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
            _add(rows, small, states, s, nxt, chunk_of(ep.actions[s:e]), text, hit,
                 len(starts) - j if reached else -1)
    return _as_transitions(rows)


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


def rollout_transitions(collection, goals: str = "both", episodes: list[int] | None = None,
                        progress=None) -> Transitions:
    """Chunk transitions of a `seal demos dagger` collection (``OUT``: ``OUT/dataset`` and
    ``OUT/annotations``), one per boundary at which the world then moved: the executed actions from
    there to the next boundary, the task goal rewarded on the last chunk of a solved episode, and a
    sub-plan goal wherever the expert's next sub-plan stays the same, rewarded on the chunk after
    which the expert names a later one (a frame the expert could not label ends a sub-plan unreached).
    """
    from pathlib import Path

    from seal.annotate.pipeline import ANNOTATIONS
    from seal.dagger import ANNOTATIONS_DIR, DATASET_DIR, read_frame_labels
    from seal.datasets import open_dataset
    from seal.datasets.lerobot import read_jsonl

    if goals not in GOAL_KINDS:
        raise InvalidInput(f"unknown goal kind {goals!r}; valid: {', '.join(GOAL_KINDS)}")
    root = Path(collection)
    ann = root / ANNOTATIONS_DIR
    if not (root / DATASET_DIR).is_dir() or not (ann / ANNOTATIONS).is_file():
        raise InvalidInput(f"{root} is not a `seal demos dagger` collection (it needs {DATASET_DIR}/ and "
                           f"{ANNOTATIONS_DIR}/{ANNOTATIONS})")
    reader = open_dataset(root / DATASET_DIR)
    records = {r["episode_index"]: r for r in read_jsonl(ann / ANNOTATIONS)[0] if r.get("status") == "ok"}
    episodes = list(range(reader.num_episodes)) if episodes is None else episodes
    parts = []
    for n, i in enumerate(episodes):
        if i not in records:
            raise InvalidInput(f"{root}: episode {i} has no labels in {ANNOTATIONS_DIR}/{ANNOTATIONS}")
        labels = read_frame_labels(ann, records[i])
        if labels["executed"] is None:
            raise InvalidInput(f"{root} was collected before DAgger kept the executed actions (2026-12-04): it has "
                               "no on-policy transitions; collect a round with the current `seal demos dagger`")
        parts.append(_rollout_episode(reader.episode(i), labels, goals))
        if progress:
            progress(n + 1, len(episodes))
    return Transitions.concat(parts)


def _rollout_episode(ep: Episode, labels: dict, goals: str) -> Transitions:
    moved = [j for j, a in enumerate(labels["executed"]) if len(a)]
    solved = bool(ep.meta.get("success", False))
    windows: list[tuple[str, list[int], bool]] = []  # (goal, boundaries in order, reached by the last one)
    if goals in ("task", "both") and moved:
        windows.append((ep.instruction, moved, solved))
    if goals in ("subplan", "both"):
        # Where the expert stands at each boundary: the position of its next sub-plan in the plans (texts
        # repeat, two "place it in the basket": the position says which), len(plans) once all are done.
        text, at, frames, last_plan = None, None, [], None
        for j in moved:
            here = parse_reasoning(labels["reasoning"][j]) if labels["valid"][j] else None
            pos = None if here is None else (len(here.plans) if here.finished else here.index)
            if text is not None and pos != at:
                # the expert has moved on to a later sub-plan here: the boundary before reached this one
                windows.append((text, frames, pos is not None and pos > at))
                text, frames = None, []
            if pos is not None and not here.finished:
                if text is None:
                    text, at, last_plan = here.now, pos, len(here.plans) - 1
                frames.append(j)
        if text is not None:  # still on it at the end: reached only if the task was (it is the last one)
            windows.append((text, frames, solved and at == last_plan))
    small = downsample(ep.agent_images)
    states = np.asarray(ep.states, dtype=np.float32)
    rows: dict[str, list] = {f: [] for f in Transitions.__dataclass_fields__}
    for text, frames, reached in windows:
        for k, j in enumerate(frames):
            hit = reached and k == len(frames) - 1
            nxt = min(j + 1, ep.length - 1)
            _add(rows, small, states, j, nxt, chunk_of(labels["executed"][j]), text, hit,
                 len(frames) - k if reached else -1)
    return _as_transitions(rows)


def _add(rows: dict[str, list], small, states, frame: int, nxt: int, action, goal: str, hit: bool,
         to_goal: int) -> None:
    """One transition: the view and state at ``frame``, the chunk, its goal and reward, the view after."""
    rows["image"].append(small[frame])
    rows["state"].append(states[frame])
    rows["action"].append(action)
    rows["goal"].append(goal)
    rows["reward"].append(float(hit))
    rows["done"].append(float(hit))
    rows["next_image"].append(small[nxt])
    rows["next_state"].append(states[nxt])
    rows["to_goal"].append(to_goal)


def _as_transitions(rows: dict[str, list]) -> Transitions:
    if not rows["reward"]:
        return Transitions(np.zeros((0, IMAGE_SIDE, IMAGE_SIDE, 3), np.uint8), np.zeros((0, 8), np.float32),
                           np.zeros((0, 7 * ACTION_HORIZON), np.float32), [], np.zeros(0, np.float32),
                           np.zeros(0, np.float32), np.zeros((0, IMAGE_SIDE, IMAGE_SIDE, 3), np.uint8),
                           np.zeros((0, 8), np.float32), np.zeros(0, np.int32))
    dtypes = {"image": np.uint8, "next_image": np.uint8, "to_goal": np.int32}
    return Transitions(**{f: (v if f == "goal" else np.asarray(v, dtype=dtypes.get(f, np.float32)))
                          for f, v in rows.items()})
