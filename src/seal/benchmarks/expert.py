"""`seal bench expert`: success of the scripted expert, clean and in its misaligned setting.

Trials run over the official init states 0..trials-1 of each task, spread over worker
processes (one world per task per process, no rendering).
"""

from __future__ import annotations

import multiprocessing as mp
import os

import numpy as np

from seal.sim.suites import get_task, task_count


def _run_task(job) -> dict:
    suite, task_id, trials, knob_name = job
    from seal.episode import run_policy_episode
    from seal.policies.expert.policy import FailureKnobs, ScriptedExpert
    from seal.sim.world import LiberoWorld

    world = LiberoWorld((suite, task_id))
    policy = ScriptedExpert.for_world(world, FailureKnobs.named(knob_name))
    wins, steps, errors = 0, [], 0
    try:
        for i in range(min(trials, world.num_init_states)):
            r = run_policy_episode(world, policy, init_index=i)
            wins += r.success
            errors += r.sim_error
            steps.append(r.steps)
    finally:
        world.close()
    return {"task": task_id, "knobs": knob_name, "success": wins / len(steps), "mean_steps": float(np.mean(steps)),
            "sim_errors": errors}


def run(args) -> dict:
    suite = args.suite
    tasks = range(task_count(suite)) if not args.tasks else [int(t) for t in args.tasks.split(",")]
    for t in tasks:
        get_task(suite, t)
    settings = ["clean"] + ([] if args.no_misaligned else ["misaligned"])
    jobs = [(suite, t, args.trials, k) for k in settings for t in tasks]
    workers = args.workers or min(len(jobs), os.cpu_count() or 1)
    with mp.get_context("spawn").Pool(workers) as pool:
        rows = pool.map(_run_task, jobs, chunksize=1)
    out: dict = {"suite": suite, "trials": args.trials}
    clean = [r for r in rows if r["knobs"] == "clean"]
    out["per_task_success"] = {str(r["task"]): round(r["success"], 3) for r in clean}
    out["mean_success"] = round(float(np.mean([r["success"] for r in clean])), 3)
    out["mean_steps"] = round(float(np.mean([r["mean_steps"] for r in clean])), 1)
    out["sim_errors"] = sum(r["sim_errors"] for r in rows)
    mis = [r for r in rows if r["knobs"] == "misaligned"]
    if mis:
        out["misaligned_per_task_success"] = {str(r["task"]): round(r["success"], 3) for r in mis}
        out["misaligned_mean_success"] = round(float(np.mean([r["success"] for r in mis])), 3)
    return out
