"""Small synthetic LeRobot datasets for the annotation tests (where simulator realism is not the point).

Each episode has a moving square on a gradient (H.264 keeps it recognisable) and recorded
sub-plans with the frame where each first held, as `seal demos record` writes them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from _v30 import write_v30

from seal.datasets import Episode, LeRobotWriter

PLANS = ["pick up the black bowl", "place it on the plate", "pick up the mug", "place it on the plate"]


def synthetic_episode(T: int, seed: int, instruction: str = "put the bowl and the mug on the plate",
                      meta: dict | None = None) -> Episode:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:224, 0:224]
    agent = np.empty((T, 224, 224, 3), np.uint8)
    for t in range(T):
        agent[t, ..., 0] = (x + 3 * t) % 256
        agent[t, ..., 1] = y
        agent[t, ..., 2] = (x + y) // 2
        agent[t, 40 + t % 100:80 + t % 100, 30 + seed * 5:70 + seed * 5] = (220, 30, 30)
    # Four sub-goals spread over the episode; odd frames on purpose (they fall between 10 fps frames).
    frames = sorted(int(f) for f in np.linspace(T * 0.2, T - 1, 4).round().astype(int) + seed % 2)
    frames = [min(f, T - 1) for f in frames]
    return Episode(instruction=instruction, agent_images=agent, wrist_images=255 - agent,
                   states=rng.normal(size=(T, 8)).astype(np.float32),
                   actions=rng.uniform(-1, 1, size=(T, 7)).astype(np.float32),
                   subplans=list(PLANS), critical_frames=frames,
                   meta={"suite": "synthetic", "task_id": 0, "init_index": seed} | (meta or {}))


def make_v21(root: Path, lengths: list[int], meta: dict | None = None) -> list[Episode]:
    """``meta``: extra recorder fields for every episode (e.g. the render model)."""
    episodes = [synthetic_episode(T, seed=i, meta=meta) for i, T in enumerate(lengths)]
    with LeRobotWriter(root, fps=20) as w:
        for e in episodes:
            w.add(e)
    return episodes


def make_v30(root: Path, lengths: list[int], fps: int = 20) -> list[Episode]:
    """A v3.0 dataset; sub-plans and critical frames as extra episode-metadata columns."""
    episodes = [synthetic_episode(T, seed=i, instruction=f"task number {i}") for i, T in enumerate(lengths)]
    write_v30(root, episodes, fps, lambda i, e: {"subplans": e.subplans, "critical_frames": e.critical_frames})
    return episodes
