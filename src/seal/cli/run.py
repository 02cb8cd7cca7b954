"""`seal run`: one steered episode of a method, with its trace, grids and video."""

from __future__ import annotations

import json
from pathlib import Path

from seal.cli.common import COUNT, INDEX, add_method_options, method_settings, warn_render


def add(sub) -> None:
    run = sub.add_parser("run", help="one steered LIBERO episode: video, trace, candidate grids, summary")
    run.add_argument("--suite", default="libero_10")
    run.add_argument("--task", type=int, default=0)
    run.add_argument("--init", type=INDEX, default=0, help="official init state index")
    methods, methods_help = _method_choices()
    run.add_argument("--method", default="seal", choices=methods, help=methods_help)
    run.add_argument("--max-steps", type=COUNT, default=None, help="default: the suite's limit")
    run.add_argument("--seed", type=int, default=0)
    run.add_argument("--no-video", action="store_true")
    run.add_argument("--no-grids", action="store_true")
    run.add_argument("--out", default="runs/demo")
    add_method_options(run)
    # the paper's background verification; --verify-order slot repeats a `seal eval` trial exactly
    run.set_defaults(func=_cmd_run, verify_order="arrival")


def _method_choices() -> tuple[list[str], str]:
    """The registered methods and a help text naming each."""
    from seal.steer.config import METHODS

    return list(METHODS.names), " | ".join(f"{n}: {METHODS.plugin(n).summary}" for n in METHODS.names)


def _cmd_run(args) -> int:
    from rich.console import Console

    from seal.steer.events import ProgressReporter
    from seal.steer.method import MethodSpec
    from seal.steer.run import run_steered

    spec = MethodSpec(method=args.method, **method_settings(args))
    console = Console(stderr=True)
    warn_render([spec])
    title = f"{spec.method} on {args.suite}/{args.task} init {args.init} (K={spec.effective_k})"
    with console.status(title) as status:
        progress = ProgressReporter(lambda text: status.update(f"{title}: {text}"))
        result = run_steered(spec, args.suite, args.task, args.init, Path(args.out), seed=args.seed,
                             max_steps=args.max_steps, video=not args.no_video, grids=not args.no_grids,
                             subscribers=(progress,))
    keys = ("task", "method", "init_index", "success", "ended_by", "sim_error", "steps", "wall_s", "subplans",
            "goal_status", "verifier_calls", "verifier_errors", "verifier_unavailable", "rounds", "fallbacks",
            "done_checks", "divergence", "timing", "trace")
    print(json.dumps({k: getattr(result, k) for k in keys}, indent=2))
    return 0
