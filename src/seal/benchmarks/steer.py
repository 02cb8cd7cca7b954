"""`seal bench steer` (success lift of SEAL over the policy alone) and `seal bench runtime`
(the paper's Fig. 6 breakdown per executed env step, as K grows)."""

from __future__ import annotations

import asyncio

import numpy as np

from seal.benchmarks.common import trials_of
from seal.errors import InvalidInput
from seal.sim.observation import IMAGE_SIZE
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
    audits: dict[str, list[bool]] = {"base": [], "seal": []}  # committed sub-plans achieved, by simulator truth
    for t in _tasks(args, "0,1,7"):
        spec = get_task(args.suite, t)
        wins = {"base": 0, "seal": 0}
        with EnvPool(spec, k=args.k, workers=args.workers) as pool:
            for trial in range(trials):
                for name, method in methods.items():
                    with build_episode(method, spec, seed=trial, pool=pool, max_steps=_max_steps(args),
                                       verifier=verifier if name == "seal" else None) as episode:
                        result = episode.run(trial % pool.task.init_states().shape[0])
                        wins[name] += result.success
                        audits[name] += [a for a in result.aligned if a is not None]
        per_task[str(t)] = {m: round(w / trials, 3) for m, w in wins.items()}
    base = float(np.mean([v["base"] for v in per_task.values()]))
    seal = float(np.mean([v["seal"] for v in per_task.values()]))
    knobs = "misaligned" if methods["seal"].policy == "scripted" else None  # the scripted expert's setting only
    return {"suite": args.suite, "trials": trials, "k": args.k, "knobs": knobs, "verifier": verifier.name,
            "policy": methods["seal"].policy,
            "max_steps": _max_steps(args),
            "base_mean_success": round(base, 3), "seal_mean_success": round(seal, 3), "lift": round(seal - base, 3),
            **{f"alignment_{m}": (round(sum(a) / len(a), 3) if a else None) for m, a in audits.items()},
            **{f"subplans_audited_{m}": len(a) for m, a in audits.items()},
            "per_task": per_task}


def _max_steps(args) -> int | None:
    return getattr(args, "max_steps", None)


class PixelReadingExpert:
    """The runtime benchmark's stand-in for a pixel policy until a learned one is given: the
    scripted expert (its chunks, its <think>s) that also asks for both cameras at ``image_size``
    at every chunk of every candidate, and reads them. Rendering then costs what it costs a VLA;
    only the network's own time is missing (``sampling_ms`` is the expert's)."""

    def __init__(self, inner, image_size: int):
        self._inner, self.image_size = inner, image_size
        self.thinks = inner.thinks
        self.pixels_read = 0

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def act(self, obs_batch, reasoning, rows=None):
        for obs in obs_batch:
            if obs.agent is None or obs.agent.shape[0] != self.image_size or obs.wrist is None:
                raise InvalidInput(f"the pixel stand-in expected both cameras at {self.image_size} px")
            self.pixels_read += int(obs.agent.size + obs.wrist.size)
        return self._inner.act(obs_batch, reasoning, rows)


PIXELS = "pixels"  # the runtime benchmark's stand-in: the scripted expert reading both cameras


def runtime_policies() -> tuple[str, ...]:
    """What `seal bench runtime --policy` takes: every policy that runs in this process (a registered
    one that is not a client of another server), and the pixel-reading stand-in."""
    from seal.policies import servable

    return (*servable(), PIXELS)


def run_runtime(args) -> dict:
    """Per executed env step, as K grows: sampling (the policy), render (both cameras for every
    candidate), predict (physics in the K worlds), verify (waiting for verdicts), total (wall).

    ``render_ms``/``predict_ms`` split the wall time of the pool's step commands by the workers'
    own measured render and physics seconds (the two run interleaved on the same cores)."""
    from dataclasses import replace

    from seal.policies import POLICIES, make_policy
    from seal.policies.base import images_for

    trials = trials_of(args, "runtime")
    try:
        ks = [int(k) for k in (args.ks or "1,2,4,8,10").split(",")]
    except ValueError:
        raise InvalidInput(f"--ks must be comma-separated K values, got {args.ks!r}") from None
    policy_name = getattr(args, "policy", None) or "scripted"
    name, colon, path = policy_name.partition(":")
    if name not in runtime_policies() or (colon and (name == PIXELS or not POLICIES.options(name).checkpoint)):
        raise InvalidInput(f"unknown --policy {policy_name!r} for bench runtime; valid: {', '.join(runtime_policies())}")
    # the stand-in is the scripted expert, misaligned as every runtime row has been
    policy_key = "scripted" if name == PIXELS else name
    options = POLICIES.options(policy_key)(**({"knobs": "misaligned"} if policy_key == "scripted" else {}))
    if colon:
        options = replace(options, **{options.checkpoint: path})
    task = _tasks(args, "5")[0]
    spec = get_task(args.suite, task)
    # what the policy reads: its state (nothing rendered), or its cameras at the size it declares
    probe = make_policy(policy_key, options, spec, seed=0)
    try:
        reads = images_for(probe, probe.privileged_atoms())
    finally:
        probe.close()
    pixel = name == PIXELS or bool(reads)
    render = getattr(args, "render", None) or ("fast" if pixel else "stock")
    image_size = getattr(args, "image_size", None) or 64
    if name != PIXELS and reads:  # a policy that reads its cameras sees them at the size it was trained at
        size = IMAGE_SIZE if reads is True else reads
        if getattr(args, "image_size", None) not in (None, size):
            raise InvalidInput(f"--image-size {args.image_size}: the {name} policy was trained at {size} px")
        image_size = size
    latencies = (0.0,) if pixel or not args.latency else (0.0, args.latency)
    rows = []
    for latency in latencies:
        for k in ks:
            workers = None if args.workers is None else min(args.workers, k)
            with EnvPool(spec, k=k, workers=workers, render_mode=render) as pool:
                if pixel:
                    pool.prepare_render((image_size,))  # set-up, not per-step time
                verifier = OracleVerifier() if latency == 0 else FixedLatencyOracle(latency)
                # arrival order: what is measured is the paper's overlap of verification and sampling
                method = MethodSpec(method="seal", k=k, render=render, verify_order="arrival", policy=policy_key,
                                    policy_options=options)
                steps = wall = succeeded = 0
                timing = {"sampling_s": 0.0, "predict_s": 0.0, "verify_wait_s": 0.0, "physics_cpu_s": 0.0,
                          "render_cpu_s": 0.0}
                for trial in range(trials):
                    # the scripted expert's rows repeat one seed (only the init state changes); any other
                    # policy's trials vary it
                    policy = make_policy(policy_key, options, spec, seed=0 if policy_key == "scripted" else trial)
                    if name == PIXELS:
                        policy = PixelReadingExpert(policy, image_size)
                    try:
                        with build_episode(method, spec, seed=0, pool=pool, verifier=verifier, policy=policy,
                                           max_steps=_max_steps(args)) as episode:
                            r = episode.run(trial)
                    finally:
                        policy.close()
                    steps += max(r.steps, 1)
                    succeeded += bool(r.success)
                    wall += r.wall_s
                    for key in timing:
                        timing[key] += r.timing.get(key, 0.0)
            per = 1000.0 / steps
            cpu = timing["physics_cpu_s"] + timing["render_cpu_s"]
            render_share = timing["render_cpu_s"] / cpu if cpu else 0.0
            rows.append({"verifier": "oracle" if latency == 0 else "fixed-latency oracle (stand-in for a VLM)",
                         "verifier_latency_s": latency, "k": k,
                         "sampling_ms": round(timing["sampling_s"] * per, 2),
                         "render_ms": round(timing["predict_s"] * render_share * per, 2),
                         "predict_ms": round(timing["predict_s"] * (1 - render_share) * per, 2),
                         "verify_ms": round(timing["verify_wait_s"] * per, 2),
                         "total_ms": round(wall * per, 2),
                         # what the per-step figures average over (a failing episode runs to max_steps)
                         "executed_steps": steps, "episodes_succeeded": succeeded})
    oracle_rows = {r["k"]: r for r in rows if r["verifier_latency_s"] == 0}
    ratio = None
    if 1 in oracle_rows and 10 in oracle_rows and oracle_rows[1]["predict_ms"] + oracle_rows[1]["render_ms"] > 0:
        ratio = round((oracle_rows[10]["predict_ms"] + oracle_rows[10]["render_ms"])
                      / (oracle_rows[1]["predict_ms"] + oracle_rows[1]["render_ms"]), 2)
    out = {"suite": args.suite, "task": task, "trials": trials, "max_steps": _max_steps(args),
           "policy": policy_name, "render": render, "image_size": image_size if pixel else None,
           "workers": args.workers, "rows": rows,
           "predict_k10_over_k1": ratio,  # physics + rendering of the K worlds, K=10 against K=1
           "verifier": STAND_IN if len(latencies) > 1 else "oracle",
           "note": "ms per executed env step; verify_ms is the time the loop waited for verdicts, amortised; "
                   "render_ms and predict_ms split the pool's step time by the workers' render and physics "
                   "seconds; total_ms also holds what no column names (sub-plan start observations, bookkeeping)."
                   + (" policy 'pixels' is the scripted expert reading both cameras at every chunk, standing "
                      "in for a learned VLA's rendering (its network time is not in sampling_ms)."
                      if name == PIXELS else "")
                   + (f" Rows with verifier_latency_s > 0 use the {STAND_IN}." if len(latencies) > 1 else "")}
    plot = getattr(args, "plot", None)
    if plot:
        from seal.report.plots import runtime_breakdown_plot

        out["plot"] = str(runtime_breakdown_plot([r for r in rows if r["verifier_latency_s"] == 0], plot,
                                                 title=f"{spec.key}, policy {policy_name}, render {render}"))
    return out
