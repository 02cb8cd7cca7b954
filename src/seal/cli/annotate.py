"""`seal annotate`: reasoning labels for a LeRobot dataset."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from seal.cli.common import COUNT, INDEX, POSITIVE


def add(sub) -> None:
    ann = sub.add_parser("annotate", help="reasoning labels for a LeRobot dataset (resumable; prints a JSON summary)")
    ann.add_argument("dataset", help="LeRobot dataset directory (v2.1 or v3.0 layout)")
    ann.add_argument("--backend", required=True, choices=["gemini", "openai", "offline"])
    ann.add_argument("--out", required=True, help="sidecar output directory (re-run with the same one to resume)")
    ann.add_argument("--episodes", default="", help="e.g. 0,3,5-9 (default: all)")
    ann.add_argument("--model", default=None, help="default: gemini-2.5-pro / gpt-4o")
    ann.add_argument("--base-url", default=None, help="server URL (default: the SDK's, e.g. OPENAI_BASE_URL)")
    ann.add_argument("--camera", default=None, help="image feature to annotate (default: the agent view)")
    ann.add_argument("--concurrency", type=COUNT, default=4, help="episodes in flight at once")
    ann.add_argument("--timeout", type=POSITIVE, default=180.0, help="seconds per model call attempt")
    ann.add_argument("--max-retries", type=INDEX, default=3, help="retries of a call on 429/5xx/timeouts")
    ann.add_argument("--max-invalid", type=INDEX, default=2, help="re-asks after a reply that fails validation")
    ann.add_argument("--frame-stride", type=COUNT, default=1, help="openai: send every n-th 10 fps frame")
    ann.add_argument("--cache-dir", default=None, help="cache valid model answers here")
    ann.add_argument("--videos", action=argparse.BooleanOptionalAction, default=None,
                     help="write the 10 fps clips into OUT/videos (default: for model backends)")
    ann.add_argument("--retry-failed", action="store_true", help="also redo episodes that failed before")
    ann.set_defaults(func=_cmd_annotate)


def _cmd_annotate(args) -> int:
    from rich.console import Console
    from seal.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from seal.annotate.backends import make_annotator
    from seal.annotate.pipeline import (RunOptions, annotate_dataset, parse_episode_list, read_annotations,
                                        summary_dict)
    from seal.annotate.quality import quality_report
    from seal.datasets import open_dataset

    reader = open_dataset(Path(args.dataset))
    episodes = parse_episode_list(args.episodes, reader.num_episodes) if args.episodes else None
    opts = {} if args.backend == "offline" else {
        "timeout_s": args.timeout, "max_retries": args.max_retries, "max_invalid": args.max_invalid,
        "frame_stride": args.frame_stride, "cache_dir": args.cache_dir}
    annotator = make_annotator(args.backend, model=args.model, base_url=args.base_url, **opts)
    options = RunOptions(episodes=episodes, camera=args.camera, concurrency=args.concurrency,
                         videos=args.videos, retry_failed=args.retry_failed)
    console = Console(stderr=True)
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console) as bar:
        job = bar.add_task(f"annotating with {annotator.backend}:{annotator.model}", total=None)

        def on_start(todo, skipped):
            bar.update(job, total=todo, description=f"{annotator.backend}: {todo} to do, {skipped} already done")

        def progress(record, s):
            bar.update(job, advance=1, description=f"{annotator.backend}: {s.annotated} ok, {s.failed} failed, "
                                                   f"${s.cost_usd:.4f}")

        summary = annotate_dataset(reader, Path(args.out), annotator, options, progress=progress, on_start=on_start)
    result = summary_dict(summary)
    result["out"] = str(Path(args.out).resolve())
    result["quality"] = quality_report(read_annotations(Path(args.out)), reader, options.horizon)
    print(json.dumps(result))
    return 0 if summary.failed == 0 else 1
