"""`seal demos record|dagger|dagger-report`: expert demonstrations and DAgger collections."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from seal.cli.common import COUNT, NONNEGATIVE
from seal.errors import InvalidInput
from seal.options import real_in


def add(sub) -> None:
    demos = sub.add_parser("demos", help="scripted-expert demonstrations as a LeRobot dataset")
    demos_sub = demos.add_subparsers(dest="demos_command", required=True)
    rec = demos_sub.add_parser("record", help="record successful expert episodes (resumable)")
    rec.add_argument("--suite", default="libero_10")
    rec.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    rec.add_argument("--episodes-per-task", type=COUNT, default=10)
    rec.add_argument("--knobs", default="clean", choices=["clean", "misaligned"])
    rec.add_argument("--out", required=True)
    rec.add_argument("--keep-failures", action="store_true",
                     help="also write failed episodes (meta success=false), e.g. as contrast for value learning")
    rec.add_argument("--starts", default="sampled", choices=["sampled", "official"],
                     help="sampled: objects and fixtures placed afresh from seeds (training data; no official "
                          "init state); official: LIBERO's init state e for episode e (evaluation states)")
    rec.add_argument("--image-size", type=COUNT, default=None,
                     help="render both cameras at this many px (e.g. 64 for a 64-px policy; lossless video); "
                          "default: openpi's 224-px view")
    rec.add_argument("--render", default="stock", choices=["stock", "fast"],
                     help="render model; record in the one the policy will be evaluated in")
    rec.add_argument("--workers", type=COUNT, default=1, help="episodes recorded in parallel (one simulator each)")
    rec.add_argument("--dart", type=NONNEGATIVE, default=0.0,
                     help="perturb each executed chunk by a Gaussian offset of this std (action units, e.g. 0.1) "
                          "and record the expert's unperturbed actions: demonstrations of recovering (DART)")
    rec.set_defaults(func=_cmd_demos)
    dag = demos_sub.add_parser("dagger", help="roll out a learned VLA on fresh starts and record the scripted "
                                              "expert's labels at every state it reaches (DAgger; resumable)")
    dag.add_argument("--ckpt", default="reason", help="the VLA to roll out: reason (shipped), twin (the pi0 baseline: its own states and chunks), or a checkpoint/run dir")
    dag.add_argument("--suite", default="libero_10")
    dag.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    dag.add_argument("--episodes-per-task", type=COUNT, default=10)
    dag.add_argument("--round", type=COUNT, default=1, help="DAgger round: each has starts of its own")
    dag.add_argument("--beta", type=real_in(0.0, 1.0), default=0.0,
                     help="share of chunks the expert executes instead of the VLA (0: the VLA alone)")
    dag.add_argument("--render", default=None, choices=["stock", "fast"],
                     help="render model (default: the one the checkpoint was trained in)")
    dag.add_argument("--max-steps", type=COUNT, default=None, help="step budget (default: the task's)")
    dag.add_argument("--teacher-check", action=argparse.BooleanOptionalAction, default=True,
                     help="after each rollout, let the expert finish alone from one of its states: how often the "
                          "teacher's labels lead somewhere (default on; ~10 s of physics per rollout)")
    dag.add_argument("--workers", type=COUNT, default=1, help="episodes in parallel (one simulator each)")
    dag.add_argument("--verifier-cases", default=None, metavar="DIR",
                     help="also write verification cases from the VLA's own states here, labelled by the oracle "
                          "(its sub-plan ends, its 'task complete', held-versus-released places; for `seal train "
                          "verifier --data`). Off by default; the rollouts and the DAgger data are the same either way")
    dag.add_argument("--out", required=True)
    dag.set_defaults(func=_cmd_dagger)
    rep = demos_sub.add_parser("dagger-report", help="figures of a DAgger collection (all its episodes so far) and "
                                                     "a contact sheet of the states the expert could not finish from")
    rep.add_argument("dir", help="a `seal demos dagger` output directory")
    rep.add_argument("--sheet", default=None, metavar="PNG", help="write the contact sheet here")
    rep.set_defaults(func=_cmd_dagger_report)


def _cmd_demos(args) -> int:
    from seal.progress import Progress

    from seal.demos import record_demos
    from seal.policies.expert.policy import FailureKnobs
    from seal.sim.suites import parse_task_ids, task_count

    tasks = None if not args.tasks else parse_task_ids(args.suite, args.tasks)
    n_tasks = task_count(args.suite) if tasks is None else len(tasks)
    with Progress() as bar:
        job = bar.add_task(f"recording {args.suite}", total=n_tasks * args.episodes_per_task)

        def progress(spec, summary, advance):
            bar.update(job, advance=advance,
                       description=f"{spec.key}: {summary.recorded} recorded, {summary.failed} failed")

        summary = record_demos(args.suite, Path(args.out), episodes_per_task=args.episodes_per_task, tasks=tasks,
                               knobs=FailureKnobs.named(args.knobs), progress=progress,
                               keep_failures=args.keep_failures, starts=args.starts, image_size=args.image_size,
                               render_mode=args.render, workers=args.workers, dart=args.dart)
    print(json.dumps(summary.__dict__))
    return 0


def _cmd_dagger(args) -> int:
    from seal.dagger import collect_dagger
    from seal.progress import Progress
    from seal.sim.suites import parse_task_ids

    tasks = None if not args.tasks else parse_task_ids(args.suite, args.tasks)
    with Progress() as bar:
        job = bar.add_task(f"DAgger round {args.round}", total=None)

        def progress(summary, total, advance):
            bar.update(job, total=total, advance=advance,
                       description=f"{summary.recorded} rollouts ({summary.successes} solved), {summary.frames} "
                                   f"labelled states, {summary.invalid_labels} without a teacher answer")

        summary = collect_dagger(args.suite, Path(args.out), ckpt=args.ckpt, episodes_per_task=args.episodes_per_task,
                                 round_=args.round, beta=args.beta, tasks=tasks, workers=args.workers,
                                 render_mode=args.render, max_steps=args.max_steps,
                                 teacher_check=args.teacher_check, verifier_cases=args.verifier_cases,
                                 progress=progress)
    print(json.dumps(summary.__dict__))
    return 0


def _cmd_dagger_report(args) -> int:
    from seal.dagger import ATTEMPTS, summarize, unrecovered_sheet

    if not (Path(args.dir) / ATTEMPTS).is_file():
        raise InvalidInput(f"{args.dir} holds no DAgger collection (no {ATTEMPTS}); give a `seal demos dagger --out` directory")
    out = summarize(Path(args.dir))
    if args.sheet:
        sheet = unrecovered_sheet(Path(args.dir), Path(args.sheet))
        out["sheet"] = str(sheet) if sheet else None
    print(json.dumps(out))
    return 0
