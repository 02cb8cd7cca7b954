"""`seal train value`: a LeRobot dataset -> a V-GPS checkpoint, with a held-out check.

Episodes are split (seeded) into training and held-out sets before any transition is made, so
the held-out figures measure generalisation to new rollouts, not to new chunks of seen ones.
The split, the settings and the held-out figures go to ``summary.json`` beside the checkpoint.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from seal.errors import InvalidInput
from seal.train.transitions import GOAL_KINDS, load_transitions


def split_episodes(n: int, holdout: float, seed: int) -> tuple[list[int], list[int]]:
    """(train, held-out) episode indices; at least one of each when holdout > 0."""
    if not 0.0 <= holdout < 1.0:
        raise InvalidInput(f"--holdout must be in [0, 1), got {holdout}")
    order = np.random.default_rng(seed).permutation(n).tolist()
    k = min(max(int(round(n * holdout)), 1), n - 1) if holdout > 0 else 0
    if n - k < 1 or (holdout > 0 and n < 2):
        raise InvalidInput(f"the dataset has {n} episode(s); need at least 2 to hold one out (or --holdout 0)")
    return sorted(order[k:]), sorted(order[:k])


def train_value_on_dataset(dataset: Path, out: Path, *, goals: str, holdout: float, cfg,
                           progress=None) -> dict:
    from seal.datasets import open_dataset
    from seal.train.vgps import evaluate_value, train_value
    from seal.value.vgps import load_scorer_nets

    if goals not in GOAL_KINDS:
        raise InvalidInput(f"unknown --goals {goals!r}; valid: {', '.join(GOAL_KINDS)}")
    reader = open_dataset(dataset)
    n = reader.num_episodes
    train_eps, held_eps = split_episodes(n, holdout, cfg.seed)
    say = progress or (lambda *a, **k: None)
    say("load", 0, len(train_eps) + len(held_eps))
    train = load_transitions(dataset, goals, train_eps, progress=lambda i, total: say("load", i, total + len(held_eps)))
    held = load_transitions(dataset, goals, held_eps) if held_eps else None
    say("train", 0, cfg.steps)
    last = train_value(train, out, cfg, progress=lambda step, m: say("train", step, cfg.steps, m),
                       image_size=reader.image_size)
    summary = {"dataset": str(dataset), "image_size": reader.image_size, "goals": goals, "config": asdict(cfg), "train_episodes": train_eps,
               "heldout_episodes": held_eps, "train_transitions": len(train), "last": last,
               "reward_rate": round(float(train.reward.mean()), 4)}
    if held is not None:
        nets, _ = load_scorer_nets(out)
        summary["heldout"] = evaluate_value(nets, held, cfg)
        summary["train_fit"] = evaluate_value(nets, train, cfg)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
