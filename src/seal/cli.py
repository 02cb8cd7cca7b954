"""The `seal` command. Thin: parse arguments, call one function, print the result."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from seal.errors import SealError


def _cmd_run(args) -> int:
    from rich.progress import Progress

    from seal.episode import run_policy_episode, write_summary
    from seal.policies.expert.policy import FailureKnobs, ScriptedExpert
    from seal.sim.world import LiberoWorld

    knobs = FailureKnobs.named(args.knobs)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    world = LiberoWorld((args.suite, args.task), render_mode=args.render)
    try:
        policy = ScriptedExpert.for_world(world, knobs, seed=args.init)
        with Progress(transient=True) as bar:
            job = bar.add_task(f"{world.task.key} init {args.init}", total=args.max_steps or world.task.max_steps)
            result = run_policy_episode(world, policy, init_index=args.init, max_steps=args.max_steps,
                                        video_path=out / "episode.mp4",
                                        progress=lambda s, n: bar.update(job, completed=s))
    finally:
        world.close()
    write_summary(result, out / "summary.json")
    print(json.dumps({k: v for k, v in result.__dict__.items() if k != "reasoning"}, indent=2))
    return 0


def _cmd_demos(args) -> int:
    from rich.progress import Progress

    from seal.demos import record_demos
    from seal.policies.expert.policy import FailureKnobs
    from seal.sim.suites import task_count

    tasks = None if not args.tasks else [int(t) for t in args.tasks.split(",")]
    n_tasks = task_count(args.suite) if tasks is None else len(tasks)
    with Progress() as bar:
        job = bar.add_task(f"recording {args.suite}", total=n_tasks * args.episodes_per_task)

        def progress(spec, summary, advance):
            bar.update(job, advance=advance,
                       description=f"{spec.key}: {summary.recorded} recorded, {summary.failed} failed")

        summary = record_demos(args.suite, Path(args.out), episodes_per_task=args.episodes_per_task, tasks=tasks,
                               knobs=FailureKnobs.named(args.knobs), progress=progress)
    print(json.dumps(summary.__dict__))
    return 0


def _cmd_bench(args) -> int:
    from seal.benchmarks import run_benchmark

    print(json.dumps(run_benchmark(args.what, args)))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="seal", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run one LIBERO episode and write a video and a summary")
    run.add_argument("--suite", default="libero_10")
    run.add_argument("--task", type=int, default=0)
    run.add_argument("--init", type=int, default=0, help="official init state index")
    run.add_argument("--max-steps", type=int, default=None, help="default: the suite's limit")
    run.add_argument("--render", default="stock", choices=["stock", "fast"])
    run.add_argument("--knobs", default="clean", choices=["clean", "misaligned"],
                     help="the scripted expert's failure setting")
    run.add_argument("--out", default="runs/demo")
    run.set_defaults(func=_cmd_run)

    demos = sub.add_parser("demos", help="scripted-expert demonstrations as a LeRobot dataset")
    demos_sub = demos.add_subparsers(dest="demos_command", required=True)
    rec = demos_sub.add_parser("record", help="record successful expert episodes (resumable)")
    rec.add_argument("--suite", default="libero_10")
    rec.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    rec.add_argument("--episodes-per-task", type=int, default=10)
    rec.add_argument("--knobs", default="clean", choices=["clean", "misaligned"])
    rec.add_argument("--out", required=True)
    rec.set_defaults(func=_cmd_demos)

    bench = sub.add_parser("bench", help="benchmarks; each prints one JSON object")
    bench.add_argument("what", choices=["sim", "expert"])
    bench.add_argument("--tasks", default="", help="expert: comma-separated task ids (default: all)")
    bench.add_argument("--trials", type=int, default=50, help="expert: init states per task")
    bench.add_argument("--no-misaligned", action="store_true", help="expert: skip the misaligned setting")
    bench.add_argument("--suite", default="libero_10")
    bench.add_argument("--task", type=int, default=0)
    bench.add_argument("--k", type=int, default=10)
    bench.add_argument("--workers", type=int, default=None)
    bench.set_defaults(func=_cmd_bench)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except SealError as exc:
        print(f"seal: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("seal: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
