"""`seal bench value`: cost of the V-GPS value function, and (with --dataset) its held-out quality.

- ``updates_per_s``: IQL gradient updates per second at batch 128 on one thread (the default),
  on random transitions of the real shapes (56x56 view, 8-d state, 5x7 chunk, goal text);
- ``score_ms_k{K}``: one `VGPSScorer.score` call ranking K chunks (the per-step cost the
  ``value`` method adds), median of 20;
- with ``--dataset DIR``: `seal train value` for ``--steps`` updates (default 300) into a
  temporary directory, then the held-out figures of its summary (return rank correlation,
  goal accuracy);
- with ``--ckpt RUN[,RUN]`` and ``--data COLL``: each trained value function scored on a policy's
  rollouts (a `seal demos dagger` collection none of them trained on): does Q rank the chunks that
  led to a goal above those that did not, for the task goal and for the sub-plan goals
  (``rollouts``, per run).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np


def _random_transitions(n: int):
    from seal.train.transitions import Transitions

    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (n, 56, 56, 3), dtype=np.uint8)
    state = rng.normal(size=(n, 8)).astype(np.float32)
    reward = (rng.random(n) < 0.1).astype(np.float32)
    goals = [f"pick up the object number {i % 7}" for i in range(n)]
    return Transitions(img, state, rng.uniform(-1, 1, (n, 35)).astype(np.float32), goals, reward, reward.copy(),
                       img, state, np.full(n, -1, np.int32))


def run(args) -> dict:
    from seal.sim.observation import Observation
    from seal.train.pipeline import train_value_on_dataset
    from seal.train.vgps import IQLConfig, train_value
    from seal.value.vgps import VGPSScorer

    k = args.k
    out: dict = {}
    if args.ckpt and args.data:
        out["rollouts"] = score_on_rollouts([c for c in args.ckpt.split(",") if c], args.data)
    with tempfile.TemporaryDirectory() as tmp:
        steps = 40
        t0 = time.perf_counter()
        train_value(_random_transitions(1024), Path(tmp) / "speed", IQLConfig(steps=steps, save_every=10_000))
        out["updates_per_s"] = round(steps / (time.perf_counter() - t0), 2)
        scorer = VGPSScorer.load(Path(tmp) / "speed")
        obs = Observation(state=np.zeros(8), prompt="", agent=np.zeros((224, 224, 3), np.uint8))
        chunks = np.random.default_rng(0).uniform(-1, 1, (k, 16, 7)).astype(np.float32)
        times = []
        for _ in range(20):
            t0 = time.perf_counter()
            scorer.score(obs, chunks, "put the bowl on the plate")
            times.append(time.perf_counter() - t0)
        out[f"score_ms_k{k}"] = round(1000 * float(np.median(times)), 2)
        if args.dataset:
            train_steps = args.steps or 300
            summary = train_value_on_dataset(Path(args.dataset), Path(tmp) / "data", goals="both", holdout=0.2,
                                             cfg=IQLConfig(steps=train_steps))
            out |= {"dataset": args.dataset, "train_steps": train_steps,
                    "train_transitions": summary["train_transitions"], "heldout": summary.get("heldout"),
                    "train_fit": summary.get("train_fit")}
    return out


def score_on_rollouts(runs: list[str], collection: str) -> dict:
    """Held-out figures of trained value functions on a rollout collection, per goal kind."""
    from seal.train.transitions import rollout_transitions
    from seal.train.vgps import IQLConfig, evaluate_value
    from seal.value.vgps import load_scorer_nets

    data = {kind: rollout_transitions(collection, kind) for kind in ("task", "subplan")}
    out = {"collection": collection,
           "episodes_solved": int(data["task"].reward.sum()), "task_transitions": len(data["task"])}
    for run in runs:
        nets, meta = load_scorer_nets(run)
        gamma = float(meta.get("config", {}).get("gamma", IQLConfig().gamma))
        out[run] = {kind: evaluate_value(nets, d, IQLConfig(gamma=gamma)) for kind, d in data.items()}
    return out
