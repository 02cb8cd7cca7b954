"""`seal eval`: methods x suites x tasks x trials into a results store."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from seal.cli.common import COUNT, add_method_options, method_settings, warn_render


def add(sub) -> None:
    ev = sub.add_parser("eval", help="methods x suites x tasks x trials into a SQLite results store (resumable)")
    ev.add_argument("--suite", default="libero_10", help="comma-separated suites")
    ev.add_argument("--methods", default="base,seal",
                    help="comma-separated methods, each optionally with settings: seal:k=5:rounds=1 (a mismatch "
                         "inside an item: seal:mismatch=1.3/0.8/1.2); the method options below apply to all")
    ev.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    ev.add_argument("--trials", type=COUNT, default=50, help="trials per task (init state = trial mod #inits)")
    ev.add_argument("--db", required=True, help="results database (created if missing, resumed if present)")
    ev.add_argument("--out", default=None, help="traces/videos directory (default: next to the database)")
    ev.add_argument("--backend", default="local", help="local | ray")
    ev.add_argument("--address", default=None, help="ray: cluster address (default: start a local one)")
    ev.add_argument("--workers", type=COUNT, default=1, help="trials run in parallel")
    ev.add_argument("--pool-workers", type=COUNT, default=1, help="simulator processes per trial worker")
    ev.add_argument("--video", default="failures", choices=["none", "failures", "all"])
    ev.add_argument("--no-grids", action="store_true")
    ev.add_argument("--max-steps", type=COUNT, default=None, help="cap episode length (default: the suite's)")
    ev.add_argument("--retry-errors", action="store_true",
                    help="run again the trials of this command stored as errors (a crashed worker, a server that "
                    "timed out); each error row stays until its new result replaces it")
    add_method_options(ev)
    ev.set_defaults(func=_cmd_eval)


def _cmd_eval(args) -> int:
    from seal.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from seal.eval.execute import RunOptions
    from seal.eval.runner import run_eval
    from seal.report.data import unique_names
    from seal.report.labels import display_name
    from seal.sim.suites import parse_task_ids
    from seal.steer.method import parse_methods

    methods = parse_methods(args.methods, **method_settings(args))
    warn_render(methods)
    suites = [s.strip() for s in args.suite.split(",") if s.strip()]
    tasks = None
    if args.tasks:  # the same ids in every suite: each must have them
        tasks = [parse_task_ids(suite, args.tasks) for suite in suites][0]
    out = args.out or str(Path(args.db).with_suffix("")) + "_runs"
    options = RunOptions(out_dir=out, video=args.video, grids=not args.no_grids, pool_workers=args.pool_workers,
                         max_steps=args.max_steps)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    # The tally reads as the report's tables do ("reasoning VLA + SEAL (oracle) 6/8"), not as stored keys.
    names = unique_names({m.label: display_name(m.canonical()) for m in methods},
                         {m.label: m.config_hash for m in methods})
    tally: dict = {}
    with Progress(*columns) as bar:
        job = bar.add_task("eval", total=None)

        def on_row(row, ran, total):
            name = names.get(row.method, row.method)
            ok, n = tally.get(name, (0, 0))
            tally[name] = (ok + row.success, n + 1)
            rates = "  ".join(f"{m} {a}/{b}" for m, (a, b) in tally.items())
            flag = " [red]error[/red]" if row.status == "error" else ""
            bar.update(job, total=total, completed=ran, description=f"{row.suite}/{row.task}  {rates}{flag}")

        summary = run_eval(args.db, methods, suites, tasks, args.trials, options=options, backend=args.backend,
                           workers=args.workers, address=args.address, on_row=on_row,
                           retry_errors=args.retry_errors)
    print(json.dumps(summary.__dict__))
    for method, n in summary.verifier_errors.items():
        if n:
            print(f"seal: warning: {method}: {n} verification(s) got no answer (verifier errors past their "
                  f"retries); {summary.verifier_unavailable[method]} trial(s) mostly unverified. See `seal report`.",
                  file=sys.stderr)
    return 0
