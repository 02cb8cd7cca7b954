"""`seal bench steer` (success lift of SEAL over the policy alone) and `seal bench runtime`
(the paper's Fig. 6 breakdown per executed env step, as K grows)."""

from __future__ import annotations

import asyncio

import numpy as np

from seal.benchmarks import trials_of
from seal.errors import InvalidInput
from seal.sim.pool import EnvPool
from seal.sim.suites import get_task, parse_task_ids
from seal.steer.build import build_episode
from seal.steer.method import MethodSpec
from seal.verify.base import Verdict
from seal.verify.oracle import OracleVerifier


STAND_IN = ("fixed-latency oracle: the simulator's ground truth delivered after a fixed sleep, a stand-in "
            "for a VLM call's latency (no model is called; its verdicts are the oracle's)")


class FixedLatencyOracle(OracleVerifier):
    """Oracle verdicts delivered after a fixed delay, standing in for a VLM call."""

    def __init__(self, latency_s: float):
        self.latency_s = latency_s

    async def verify(self, request) -> Verdict:
        await asyncio.sleep(self.latency_s)
        verdict = await super().verify(request)
        verdict.latency_s = self.latency_s
        return verdict


def _tasks(args, default: str) -> list[int]:
    return parse_task_ids(args.suite, args.tasks or default)


def run_steer(args) -> dict:
    from seal.verify import verifier_for

    trials = trials_of(args, "steer")
    per_task = {}
    verifier_name = getattr(args, "verifier", None) or "oracle"
    extra = {"policy": args.policy} if getattr(args, "policy", None) else {}
    if getattr(args, "model", None) and ":" not in verifier_name:
        extra["model"] = args.model
    methods = {m: MethodSpec(method=m, k=args.k, knobs="misaligned", verifier=verifier_name, **extra)
               for m in ("base", "seal")}
    # One verifier for every episode (a learned one loads its checkpoint once); episodes borrow it.
    verifier = verifier_for(methods["seal"])
    for t in _tasks(args, "0,1,7"):
        spec = get_task(args.suite, t)
        wins = {"base": 0, "seal": 0}
        with EnvPool(spec, k=args.k, workers=args.workers) as pool:
            for trial in range(trials):
                for name, method in methods.items():
                    with build_episode(method, spec, seed=trial, pool=pool, max_steps=_max_steps(args),
                                       verifier=verifier if name == "seal" else None) as episode:
                        wins[name] += episode.run(trial % pool.task.init_states().shape[0]).success
        per_task[str(t)] = {m: round(w / trials, 3) for m, w in wins.items()}
    base = float(np.mean([v["base"] for v in per_task.values()]))
    seal = float(np.mean([v["seal"] for v in per_task.values()]))
    return {"suite": args.suite, "trials": trials, "k": args.k, "knobs": "misaligned", "verifier": verifier.name,
            "policy": methods["seal"].policy,
            "max_steps": _max_steps(args),
            "base_mean_success": round(base, 3), "seal_mean_success": round(seal, 3), "lift": round(seal - base, 3),
            "per_task": per_task}


def _max_steps(args) -> int | None:
    return getattr(args, "max_steps", None)


def run_runtime(args) -> dict:
    trials = trials_of(args, "runtime")
    try:
        ks = [int(k) for k in (args.ks or "1,2,4,8,10").split(",")]
    except ValueError:
        raise InvalidInput(f"--ks must be comma-separated K values, got {args.ks!r}") from None
    task = _tasks(args, "5")[0]
    spec = get_task(args.suite, task)
    rows = []
    for latency in (0.0, args.latency):
        for k in ks:
            with EnvPool(spec, k=k, workers=args.workers) as pool:
                verifier = OracleVerifier() if latency == 0 else FixedLatencyOracle(latency)
                method = MethodSpec(method="seal", k=k, knobs="misaligned")
                steps = wall = 0
                timing = {"sampling_s": 0.0, "predict_s": 0.0, "verify_wait_s": 0.0}
                for trial in range(trials):
                    with build_episode(method, spec, seed=0, pool=pool, verifier=verifier,
                                       max_steps=_max_steps(args)) as episode:
                        r = episode.run(trial)
                    steps += max(r.steps, 1)
                    wall += r.wall_s
                    for key in timing:
                        timing[key] += r.timing[key]
            per = 1000.0 / steps
            rows.append({"verifier": "oracle" if latency == 0 else "fixed-latency oracle (stand-in for a VLM)",
                         "verifier_latency_s": latency, "k": k,
                         "sampling_ms": round(timing["sampling_s"] * per, 2),
                         "predict_ms": round(timing["predict_s"] * per, 2),
                         "verify_ms": round(timing["verify_wait_s"] * per, 2),
                         "total_ms": round(wall * per, 2)})
    return {"suite": args.suite, "task": task, "trials": trials, "max_steps": _max_steps(args), "rows": rows,
            "verifier": STAND_IN if args.latency > 0 else "oracle",
            "note": "ms per executed env step; verify_ms is the time the loop waited for verdicts, amortised. "
                    f"Rows with verifier_latency_s > 0 use the {STAND_IN}."}
