"""`seal bench annotate`: annotation throughput and agreement with the expert's ground truth.

Annotates every episode of ``--dataset`` into a fresh temporary sidecar and compares the labels
with the true sub-goal times the dataset records. The offline annotator is timed as the median
of three runs (it is fast and the machine is noisy); a model backend runs once (it costs money).
"""

from __future__ import annotations

import statistics
import tempfile
from pathlib import Path

from seal.annotate.backends import make_annotator
from seal.annotate.pipeline import RunOptions, annotate_dataset, read_annotations
from seal.annotate.quality import quality_report
from seal.datasets import open_dataset
from seal.errors import InvalidInput


def run(args) -> dict:
    if not getattr(args, "dataset", None):
        raise InvalidInput("seal bench annotate needs --dataset DIR (a LeRobot dataset, e.g. from `seal demos record`)")
    backend = getattr(args, "backend", None) or "offline"
    reader = open_dataset(Path(args.dataset))
    if reader.num_episodes == 0:
        raise InvalidInput(f"{args.dataset} has no episodes")
    repeats = 3 if backend == "offline" else 1
    rates, summary, report = [], None, None
    for _ in range(repeats):
        annotator = make_annotator(backend, model=getattr(args, "model", None), base_url=getattr(args, "base_url", None))
        with tempfile.TemporaryDirectory(prefix="seal-bench-annotate-") as tmp:
            summary = annotate_dataset(reader, Path(tmp) / "out", annotator, RunOptions())
            report = quality_report(read_annotations(Path(tmp) / "out"), reader, RunOptions().horizon)
        rates.append(summary.selected / summary.wall_s if summary.wall_s > 0 else float("inf"))
    return {
        "benchmark": "annotate",
        "backend": backend,
        "model": annotator.model,
        "dataset": str(Path(args.dataset).resolve()),
        "episodes": summary.selected,
        "failed": summary.failed,
        "episodes_per_s": round(statistics.median(rates), 3),
        "repeats": repeats,
        "agreement": report["agreement"],
        **({"agreement_is": "by construction: the offline annotator copies the recorded ground truth, so this "
                            "checks the parse/align pipeline, it is not a measurement of annotation quality"}
           if backend == "offline" else {}),
        "plan_count_agreement": report["plan_count_agreement"],
        "frame_err_mean": report["frame_err_mean"],
        "frame_err_p90": report["frame_err_p90"],
        "frame_err_unit": report["frame_err_unit"],
        "now_mismatch": report["now_mismatch"],
        "labels": report["labels"],
        "max_tokens": summary.max_tokens,
        "over_budget": summary.over_budget,
        "cost_usd": summary.cost_usd,
    }
