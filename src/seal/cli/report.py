"""`seal report`: tables, plots and HTML from a results store."""

from __future__ import annotations

import json
from pathlib import Path


def add(sub) -> None:
    rep = sub.add_parser("report", help="Markdown/CSV tables, plots and an HTML report from a results database")
    rep.add_argument("db", help="results database written by `seal eval`")
    rep.add_argument("--out", default=None, help="report directory (default: <db without suffix>_report)")
    rep.add_argument("--runs", default=None, help="trial files directory if moved (default: stored paths, "
                     "then <db without suffix>_runs)")
    rep.add_argument("--media", default="copy", choices=["copy", "link", "none"],
                     help="videos and grids: copy into the report, link relatively, or leave out")
    rep.add_argument("--paper-training", default="libero_100",
                     help="the paper's training set shown beside ours: libero_10 | libero_100 | libero_100_basket")
    rep.add_argument("--no-episodes", action="store_true", help="skip the per-episode pages")
    rep.add_argument("--suites", default="", help="comma-separated suites to report (default: all in the database)")
    rep.add_argument("--methods", default="",
                     help="';'-separated method configurations to report, each a readable label, a part of the "
                          "stored method string (policy_ckpt=563400068f48) or a config-hash prefix (default: all)")
    rep.set_defaults(func=_cmd_report)


def _cmd_report(args) -> int:
    from seal.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from seal.report import write_report

    out = args.out or str(Path(args.db).with_suffix("")) + "_report"
    with Progress(TextColumn("episode pages"), BarColumn(), MofNCompleteColumn(), transient=True) as bar:
        job = bar.add_task("pages", total=None)
        paths = write_report(args.db, out, runs_dir=args.runs, media=args.media, paper_training=args.paper_training,
                             episodes=not args.no_episodes, suites=[x for x in args.suites.split(",") if x] or None,
                             methods=[x for x in args.methods.split(";") if x.strip()] or None,
                             progress=lambda done, total: bar.update(job, completed=done, total=total))
    print(json.dumps({"index": str(paths.index_html), "markdown": str(paths.markdown),
                      "csv": [str(p) for p in paths.csv], "plots": [str(p) for p in paths.plots],
                      "episode_pages": len(paths.episodes)}))
    return 0
