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
                           rollouts: list[Path] = (), progress=None) -> dict:
    """Demonstrations (``dataset``) and, optionally, a policy's own rollouts (``rollouts``: `seal demos
    dagger` collections, failures included) -> a V-GPS checkpoint. Each source's episodes are split
    apart; the held-out figures are reported per kind of data."""
    from seal.datasets import open_dataset
    from seal.train.transitions import Transitions, rollout_transitions
    from seal.train.vgps import evaluate_value, train_value
    from seal.value.vgps import load_scorer_nets

    if goals not in GOAL_KINDS:
        raise InvalidInput(f"unknown --goals {goals!r}; valid: {', '.join(GOAL_KINDS)}")
    reader = open_dataset(dataset)
    n = reader.num_episodes
    train_eps, held_eps = split_episodes(n, holdout, cfg.seed)
    splits = {}
    for path in rollouts:
        from seal.dagger import DATASET_DIR

        rollout_reader = open_dataset(Path(path) / DATASET_DIR)
        if rollout_reader.image_size != reader.image_size:  # the Q-function scores one view size at run time
            raise InvalidInput(f"--rollouts {path} has {rollout_reader.image_size}-px views, the demonstrations "
                               f"{reader.image_size}-px: train on rollouts of a policy that sees what the demonstrations show")
        splits[str(path)] = split_episodes(rollout_reader.num_episodes, holdout, cfg.seed)
    total = n + sum(len(a) + len(b) for a, b in splits.values())
    say = progress or (lambda *a, **k: None)
    done = 0

    def counted(i, _):
        say("load", done + i, total)

    say("load", 0, total)
    train = load_transitions(dataset, goals, train_eps, progress=counted)
    done += len(train_eps)
    held = load_transitions(dataset, goals, held_eps, progress=counted) if held_eps else None
    done += len(held_eps)
    on_train, on_held = [], []
    for path, (tr, he) in splits.items():
        on_train.append(rollout_transitions(path, goals, tr, progress=counted))
        done += len(tr)
        if he:
            on_held.append(rollout_transitions(path, goals, he, progress=counted))
            done += len(he)
    demo_transitions = len(train)
    if on_train:
        train = Transitions.concat([train, *on_train])
    say("train", 0, cfg.steps)
    last = train_value(train, out, cfg, progress=lambda step, m: say("train", step, cfg.steps, m),
                       image_size=reader.image_size)
    summary = {"dataset": str(dataset), "image_size": reader.image_size, "goals": goals, "config": asdict(cfg), "train_episodes": train_eps,
               "heldout_episodes": held_eps, "train_transitions": len(train), "last": last,
               "reward_rate": round(float(train.reward.mean()), 4)}
    if splits:
        summary["rollouts"] = {path: {"train_episodes": tr, "heldout_episodes": he} for path, (tr, he) in splits.items()}
        summary["rollout_transitions"] = len(train) - demo_transitions
    if held is not None or on_held:
        nets, _ = load_scorer_nets(out)
        if held is not None:
            summary["heldout"] = evaluate_value(nets, held, cfg)
        if on_held:
            # the figure that matters for re-ranking a policy's samples: does Q tell its chunks that
            # lead to the goal from those that do not, on rollouts it never trained on
            summary["heldout_rollouts"] = evaluate_value(nets, Transitions.concat(on_held), cfg)
        summary["train_fit"] = evaluate_value(nets, train, cfg)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
