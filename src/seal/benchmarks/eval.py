"""`seal bench eval`: how fast the evaluation harness turns trials into rows on this machine.

- trials_per_hour_base / _seal: full episodes (misaligned scripted expert, oracle verifier,
  K=10 for seal) through the local backend with ``--workers`` processes, end to end (pool
  builds, videos off, store writes included).
- harness_overhead_s: per trial, everything but stepping, the policy and waiting for verdicts
  (the steerer's own timers), i.e. what the harness adds: pool building, resets, observation
  round trips, traces, IPC, the store.
- with ``--policy vla[:CKPT]`` the two methods steer that learned policy (its own render) instead;
- with ``--stock-step`` the SEAL trials run a second time on robosuite's own control step (the same
  episodes: the fast step is bit-identical) and ``fast_step_trials_per_hour_ratio`` is fast over stock,
  both in this one run;
- ray_vs_local: throughput of the Ray backend over the local backend on the same base trials,
  2 workers each (a ratio within one run, since this machine is shared and noisy), on
  max(--trials, 2) trials per task.

``--trials`` (default 3 per task) is run as given; ``--max-steps`` caps each episode (smoke runs).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path

from seal.benchmarks.common import trials_of
from seal.eval.execute import RunOptions
from seal.eval.runner import run_eval
from seal.eval.store import ResultStore
from seal.sim.suites import parse_task_ids
from seal.eval.trials import parse_methods


def _timed_run(db: Path, methods, suite, tasks, trials, options, **kw) -> tuple[float, list]:
    t0 = time.perf_counter()
    run_eval(str(db), methods, [suite], tasks, trials, options=options, **kw)
    elapsed = time.perf_counter() - t0
    with ResultStore(db) as store:
        return elapsed, store.rows()


def run(args) -> dict:
    suite = args.suite
    tasks = parse_task_ids(args.suite, args.tasks or "0")
    trials = trials_of(args, "eval")  # as given (default 3): never silently replaced
    workers = args.workers or 1
    max_steps = getattr(args, "max_steps", None)
    out: dict = {"suite": suite, "tasks": tasks, "trials_per_task": trials, "workers": workers, "k": args.k,
                 "max_steps": max_steps}
    with tempfile.TemporaryDirectory(prefix="seal-bench-eval-") as tmp:
        tmp = Path(tmp)
        options = RunOptions(out_dir=str(tmp / "runs"), video="none", grids=False, pool_workers=1,
                             max_steps=max_steps)
        overheads = []
        policy = getattr(args, "policy", None) or "scripted"
        out["policy"] = policy
        base, seal = parse_methods(f"base:policy={policy},seal:policy={policy}:k={args.k}:verifier=oracle")
        for method in (base, seal):
            elapsed, rows = _timed_run(tmp / f"{method.method}.db", [method], suite, tasks, trials,
                                       replace(options, pool_workers=1 if method.method == "base" else 2), workers=workers)
            n = len(rows)
            out[f"trials_run_{method.method}"] = n
            out[f"trials_per_hour_{method.method}"] = round(3600 * n / elapsed, 1)
            out[f"success_{method.method}"] = round(sum(r.success for r in rows) / n, 3)
            out[f"mean_steps_{method.method}"] = round(sum(r.steps for r in rows) / n, 1)
            busy = sum(r.step_s + r.policy_s + r.verify_wait_s for r in rows)
            overheads.append((elapsed * workers - busy) / n)
            out[f"harness_overhead_s_{method.method}"] = round(overheads[-1], 2)
            if method is seal and getattr(args, "stock_step", False):
                stock_s, stock_rows = _timed_run(tmp / "seal_stock.db", [method], suite, tasks, trials,
                                                 replace(options, pool_workers=2, stock_step=True), workers=workers)
                out["trials_per_hour_seal_stock_step"] = round(3600 * len(stock_rows) / stock_s, 1)
                out["fast_step_trials_per_hour_ratio"] = round(stock_s / elapsed, 3)
                # bit-identical steps: the same episodes, step for step
                out["stock_step_same_episodes"] = ([(r.trial, r.steps, r.success) for r in stock_rows]
                                                   == [(r.trial, r.steps, r.success) for r in rows])
        out["harness_overhead_s"] = round(sum(overheads) / len(overheads), 2)
        if getattr(args, "no_ray", False):
            return out
        base = [parse_methods("base")[0]]
        both = max(trials, 2)  # two workers each need a trial
        t_local, _ = _timed_run(tmp / "local2.db", base, suite, tasks, both, options, workers=2)
        t_ray, _ = _timed_run(tmp / "ray2.db", base, suite, tasks, both, options, workers=2, backend="ray")
        out["ray_vs_local_trials_per_task"] = both
        out["local_2w_s"], out["ray_2w_s"] = round(t_local, 1), round(t_ray, 1)
        out["ray_vs_local"] = round(t_local / t_ray, 3)
    return out
