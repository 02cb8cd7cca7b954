"""The `seal` command. Thin: parse arguments, call one function, print the result."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from seal.errors import SealError


def _cmd_run(args) -> int:
    from rich.progress import Progress

    from seal.episode import run_episode
    from seal.policies.reach import ReachPolicy
    from seal.sim.world import LiberoWorld

    world = LiberoWorld((args.suite, args.task), render_mode=args.render)
    with Progress(transient=True) as bar:
        job = bar.add_task(f"{world.task.key} init {args.init}", total=args.max_steps or world.task.max_steps)
        summary = run_episode(world, ReachPolicy(), init_index=args.init, out_dir=Path(args.out),
                              max_steps=args.max_steps, progress=lambda s, n: bar.update(job, completed=s))
    world.close()
    print(json.dumps(summary.__dict__, indent=2))
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
    run.add_argument("--out", default="runs/demo")
    run.set_defaults(func=_cmd_run)

    bench = sub.add_parser("bench", help="benchmarks; each prints one JSON object")
    bench.add_argument("what", choices=["sim"])
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
