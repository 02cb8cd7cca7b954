"""Synthetic verification cases in the real on-disk layout (no simulator): a block that the
sub-plan names must show up in the final views for the case to be a success."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seal.verify import dataset as ds

COLORS = {"red": (220, 30, 30), "blue": (30, 60, 220)}
OBJECTS = ["red_block_1", "blue_block_1", "table_region"]


def _scene(rng, color: str | None) -> tuple[np.ndarray, np.ndarray]:
    """(agent, wrist) 224 px views: grey noise, plus a coloured block when ``color`` is held."""
    ramp = np.linspace(0, 40, 224, dtype=np.float32)[None, :, None]  # smooth: quick to PNG-encode
    agent = (rng.integers(70, 130, 3)[None, None, :] + ramp).clip(0, 255).astype(np.uint8).repeat(224, 0)
    wrist = (rng.integers(70, 130, 3)[None, None, :] + ramp.transpose(1, 0, 2)).clip(0, 255).astype(np.uint8)
    wrist = wrist.repeat(224, 1)
    if color is not None:
        y, x = rng.integers(40, 150, 2)
        agent[y:y + 40, x:x + 40] = COLORS[color]
        wrist[140:210, 70:150] = COLORS[color]
    return agent, wrist


def make_row(i: int, *, task: str = "libero_10/0", init_index: int = 0, seed: int = 0, label: bool | None = None,
             kind_word: str = "pick up") -> dict:
    rng = np.random.default_rng([seed, i])
    target = "red" if rng.random() < 0.5 else "blue"
    success = bool(rng.random() < 0.5) if label is None else label
    held = target if success else (None if rng.random() < 0.5 else ("blue" if target == "red" else "red"))
    first, _ = _scene(rng, None)
    final, wrist = _scene(rng, held)
    subplan = f"{kind_word} the {target} block"
    atom = f"Grasped({target}_block_1)"
    suite, task_id = task.split("/")
    return {"case_id": f"{task}:fresh-train:{init_index}:e{i}:s1:r0:c0:16", "suite": suite, "task_id": int(task_id),
            "task": task, "init_source": "fresh-train", "init_index": init_index, "init_seed": 1000 + init_index,
            "episode": i, "seed": i, "policy": "scripted", "knobs": "misaligned",
            "instruction": f"pick up the {target} block", "plans": [subplan], "subplan": subplan,
            "subplan_index": 0, "subplan_number": 1, "kind": ds.subplan_kind(subplan, [atom]), "round": 0,
            "candidate": 0, "steps": 16, "ended_by": "think", "label": success, "atoms": [atom],
            "atom_values": [success], "objects": OBJECTS, "first_agent": ds.encode_png(first),
            "final_agent": ds.encode_png(final), "final_wrist": ds.encode_png(wrist)}


def write_cases(root: Path, n: int, *, tasks=("libero_10/0",), inits: int = 4, seed: int = 0) -> Path:
    """``n`` cases per task spread over ``inits`` init states, one shard per task."""
    for t, task in enumerate(tasks):
        rows = [make_row(i, task=task, init_index=i % inits, seed=seed * 100 + t) for i in range(n)]
        suite, task_id = task.split("/")
        ds.write_shard(root, ds.shard_name(suite, int(task_id), 0), rows)
    ds.write_info(root, {"collection": {"settings": {"synthetic": True}}})
    return root
