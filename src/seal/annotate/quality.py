"""How close an annotator comes to the expert's recorded ground truth.

Per annotated episode whose dataset records sub-plans and critical frames (``seal demos
record`` writes them):

- plan-count agreement: the annotator found as many plans as the expert used;
- |delta frame|: for episodes with the same count, the distance in *dataset* frames between the
  k-th critical moment and the k-th true one (truth -1 = never held: skipped);
- "now" mismatch: share of chunk labels whose current plan differs from the truth's. With equal
  plan counts the current plans are compared by position (a model words steps its own way);
  otherwise by their text, lower-cased with spaces and punctuation normalised;
- agreement: share of chunk labels whose whole reasoning text equals the truth's (1.0 for the
  offline annotator by construction, and a strict bar for any model).
"""

from __future__ import annotations

import re

import numpy as np

from seal.annotate.align import chunk_labels
from seal.datasets.lerobot import LeRobotReader


def _norm(text: str) -> str:
    return " ".join(re.sub(r"[^\w\s]", " ", text.lower()).split())


def compare_episode(record: dict, truth_plans: list[str], truth_frames: list[int], horizon: int) -> dict:
    plans = list(record["plans"])
    frames = [int(m["dataset_frame"]) for m in record["critical_moments"]]
    length = int(record["length"])
    mine = chunk_labels(plans, frames, length, horizon)
    true = chunk_labels(truth_plans, truth_frames, length, horizon)
    same_count = len(plans) == len(truth_plans)
    errors = [abs(f - t) for f, t in zip(frames, truth_frames) if t >= 0] if same_count else []
    now_diff = 0
    for a, b in zip(mine, true):
        if same_count:
            now_diff += len(a.reasoning.done) != len(b.reasoning.done)
        else:
            now_diff += _norm(a.reasoning.now) != _norm(b.reasoning.now)
    return {"episode_index": record["episode_index"], "plan_count_match": same_count, "frame_errors": errors,
            "labels": len(true), "labels_equal": sum(a.text == b.text for a, b in zip(mine, true)),
            "now_differs": now_diff}


def quality_report(records: dict[int, dict], reader: LeRobotReader, horizon: int) -> dict:
    """Aggregate :func:`compare_episode` over the committed records of one annotation run."""
    rows, failed, no_truth = [], 0, 0
    for episode, record in sorted(records.items()):
        if record["status"] != "ok":
            failed += 1
            continue
        meta = reader.episode_meta(episode)
        plans, frames = list(meta.get("subplans") or []), [int(f) for f in meta.get("critical_frames") or []]
        if not plans or len(plans) != len(frames):
            no_truth += 1
            continue
        rows.append(compare_episode(record, plans, frames, horizon))
    errors = np.array([e for r in rows for e in r["frame_errors"]], dtype=float)
    labels = sum(r["labels"] for r in rows)
    share = lambda k: round(sum(r[k] for r in rows) / labels, 4) if labels else None
    return {
        "episodes": len(records),
        "compared": len(rows),
        "failed": failed,
        "without_ground_truth": no_truth,
        "plan_count_agreement": round(float(np.mean([r["plan_count_match"] for r in rows])), 4) if rows else None,
        "frame_err_mean": round(float(errors.mean()), 3) if errors.size else None,
        "frame_err_p90": round(float(np.percentile(errors, 90)), 3) if errors.size else None,
        "frame_err_unit": f"dataset frames ({reader.fps} fps)",
        "now_mismatch": share("now_differs"),
        "agreement": share("labels_equal"),
        "labels": labels,
    }
