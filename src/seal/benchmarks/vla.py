"""`seal bench vla`: what the learned VLA costs, and (with --annotations) how good it is.

- ``params``: parameter count; ``weights``: "checkpoint" or "random-init" (no --ckpt: a fresh
  model of the default `VLAConfig`, so the costs are real and the quality figures are null);
- ``prefix_ms``: one prefix encode (two 64-px images, state, instruction), batch 1;
- ``reason_ms``: one reasoning text, ``reason(obs)``: prefix + greedy decoding with the KV cache
  (``reason_tokens`` says how long the text was; a random-init model never closes with <act>,
  so it decodes the full ``max_reasoning_tokens``: the worst case);
- ``sample_ms_k1`` / ``sample_ms_k10``: one ``act`` call for 1 / 10 rows that show the same
  observation: one prefix + reasoning encode, its expert keys/values expanded to K rows, and K
  chunks sampled in one batch (``flow_steps`` Euler steps);
- ``sample_ms_k10_nocache``: the same 10 chunks as 10 independent passes (prefix, reasoning and
  sampling each time), what a policy without a shared prefix pays;
- ``sample_ms_k1_bf16`` / ``sample_ms_k10_bf16``: the same calls with the policy's bf16 autocast on;
- ``sample_ms_k10_distinct_obs``: 10 rows with 10 different observations, as after a round's first
  chunk (every candidate in its own world): 10 prefixes encoded in one batch;
- ``sample_ms_k1_2threads``: ``sample_ms_k1`` with two torch threads instead of the policy's one;
- ``train_samples_per_s``: training throughput at batch 32 with the default `TrainConfig`
  (bf16 autocast, one thread), on a synthetic batch of the real shapes;
- ``subplan_accuracy`` / ``action_mse``: `seal.train.vla.evaluate` on held-out episodes (the
  checkpoint manifest's, else the trainer's split) when --annotations is given; else null.

- ``--rollouts N`` (with --ckpt): N closed-loop episodes of the policy alone per task (``--tasks``,
  default all of ``--suite``, LIBERO-10 unless told) from fresh sampled starts that neither a recording (episodes below
  `ROLLOUT_EPISODE0`) nor an evaluation (official init states) uses, in ``--render`` mode (default
  fast): ``rollout_success``, ``rollout_subgoals`` (share of the task's goal atoms that hold at the
  end: partial progress) and one row per episode in ``rollouts``. A check of a run in progress
  that never touches the evaluation starts. For a reasoning model the scripted expert reads every
  state the VLA reaches (`seal.dagger`, the expert never acting), adding ``onpolicy_subplan_accuracy``
  (chunk boundaries where the VLA's sub-plan is the one the expert says is next),
  ``onpolicy_alignment`` (sub-plans it acted on that were done when it moved on), ``vla_done_early``
  (episodes it ended by declaring the task done while it was not) and ``teacher_unanswered``.
  A suite derived from LIBERO-10 (``--suite lang_rephrase``...) starts each task where the LIBERO-10
  task it derives from starts (`rollout_start_seed`): in the language suites the scene, the start and
  the goal are the same and only the instruction's words differ, episode for episode.
- ``--size NAME``: without --ckpt, time the preset ``SIZES[NAME]`` instead of the default config;
- ``--sizes S,M,L``: ``train_grid``, one row per preset x (bf16, fp32) x (1, 2 threads) with the
  median seconds per training step at batch 32 (how the default config was chosen).

Timings are medians of ``--trials`` repetitions (default 5) with one torch thread; the three
sampling figures are taken in turns within each repetition, so load changes hit them alike.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from seal.benchmarks.common import median_ms
from seal.errors import InvalidInput

ROLLOUT_EPISODE0 = 1000  # rollout starts: start_seed(task, 1000 + e); recordings use episodes below 1000


def rollout_start_seed(task, e: int) -> int:
    """The seed of held-out start ``e`` of ``task`` (a `TaskSpec`): a derived suite's task draws it from
    the LIBERO-10 task it derives from, so its rollouts pair start for start with LIBERO-10's."""
    from seal.demos import start_seed

    return start_seed(task.base_key or task.key, ROLLOUT_EPISODE0 + e)


# Candidate sizes (fields of VLAConfig that differ from its defaults); "M" is the default.
SIZES = {
    "S": {"d_model": 192},
    "M": {},
    "L": {"n_layers": 6, "d_expert": 192, "expert_layers": 3},
    "M-p8": {"patch": 8},  # 64 image tokens per camera instead of 16
    "M-e192x3": {"d_expert": 192, "expert_layers": 3},
}


def _config(name: str, vocab_size: int):
    from seal.policies.vla.model import VLAConfig

    if name not in SIZES:
        raise InvalidInput(f"unknown VLA size {name!r}; valid: {', '.join(SIZES)}")
    return VLAConfig(vocab_size=vocab_size, **SIZES[name])


def train_step_s(cfg, *, batch: int, bf16: bool, threads: int, reps: int) -> float:
    """Median seconds of one training step (forward, backward, AdamW) on a synthetic batch."""
    import torch

    from seal.policies.vla.model import VLAModel
    from seal.train.vla import synthetic_batch

    torch.set_num_threads(threads)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        model = VLAModel(cfg).train()
    opt = torch.optim.AdamW(model.parameters(), lr=1e-4)
    data = synthetic_batch(cfg, batch)
    gen = torch.Generator().manual_seed(0)

    def step():
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            loss, _ = model.loss(data, gen)
        opt.zero_grad()
        loss.backward()
        opt.step()

    return round(_median_ms(step, reps) / 1000, 3)


def _interleaved_ms(fns, reps: int) -> list[float]:
    """Median ms of each function, the functions taking turns within every repetition."""
    for fn in fns:
        fn()
    times: list[list[float]] = [[] for _ in fns]
    for _ in range(reps):
        for fn, t in zip(fns, times):
            t0 = time.perf_counter()
            fn()
            t.append(time.perf_counter() - t0)
    return [round(1000 * float(np.median(t)), 2) for t in times]


def _median_ms(fn, reps: int) -> float:
    return round(median_ms(fn, reps, warmup=True), 2)


def run(args) -> dict:
    if getattr(args, "redraw", False):
        return redraw_rounds(args.round_log, getattr(args, "round", None), getattr(args, "plot", None))
    import torch

    from seal.policies.base import Reasoning
    from seal.policies.vla.checkpoint import load_checkpoint
    from seal.policies.vla.locate import resolve_checkpoint
    from seal.policies.vla.model import VLAModel, count_parameters
    from seal.policies.vla.policy import VLAPolicy
    from seal.policies.vla.tokenizer import project_texts, train_tokenizer
    from seal.sim.observation import Observation
    from seal.train.vla import TrainConfig, heldout_eval, native_bf16

    torch.set_num_threads(1)
    reps = getattr(args, "trials", None) or 5
    out: dict = {}
    if args.ckpt:
        path = resolve_checkpoint(args.ckpt)
        model, tok, manifest = load_checkpoint(path)
        out |= {"weights": "checkpoint", "ckpt": str(path)}
    else:
        tok = train_tokenizer(project_texts())
        size = getattr(args, "size", None) or "M"
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(0)
            model, manifest = VLAModel(_config(size, tok.vocab_size)).eval(), {}
        out |= {"weights": "random-init", "size": size}
    cfg = model.cfg
    out |= {"params": count_parameters(model), "reasoning": cfg.reasoning, "image_size": cfg.image_size,
            "tokens": cfg.total_tokens}
    instruction = "put both the alphabet soup and the tomato sauce in the basket"
    plans = ("pick up the alphabet soup", "place it in the basket", "pick up the tomato sauce", "place it in the basket")
    reasoning = Reasoning(plans=plans, done=plans[:1], now=plans[1])
    rng = np.random.default_rng(0)
    image = lambda: rng.integers(0, 256, (cfg.image_size, cfg.image_size, 3), dtype=np.uint8)
    obs = Observation(state=rng.normal(size=8), prompt=instruction, agent=image(), wrist=image())
    policy = VLAPolicy(model, tok, instruction=instruction)
    policy.reset(instruction, 0)
    with torch.inference_mode():
        out["prefix_ms"] = _median_ms(lambda: policy.encode([obs]), reps)
    if cfg.reasoning:
        out["reason_ms"] = _median_ms(lambda: policy.reason(obs), max(1, reps // 2))
        out["reason_tokens"] = policy.last_tokens
    else:
        out["reason_ms"] = None  # the twin writes no reasoning

    def act(k: int):
        policy.begin(k)
        return policy.act([obs] * k, reasoning)

    def nocache(k: int):
        policy.begin(k)
        return [policy.act([obs], reasoning, rows=[r]) for r in range(k)]

    def bf16(fn):
        def run():
            policy.bf16 = True
            try:
                return fn()
            finally:
                policy.bf16 = False
        return run

    # after a round's first chunk every candidate has its own observation: K prefixes, one batch
    distinct = [Observation(state=rng.normal(size=8), prompt=instruction, agent=image(), wrist=image())
                for _ in range(10)]

    def act_distinct():
        policy.begin(10)
        return policy.act(distinct, reasoning)

    def two_threads(fn):  # the policy's default is one intra-op thread; this is what two cost
        def run():
            torch.set_num_threads(2)
            try:
                return fn()
            finally:
                torch.set_num_threads(1)
        return run

    # interleaved, so that a load change on this shared machine hits all of them alike
    k1, k10, k10_nocache, k1_bf16, k10_bf16, k10_distinct, k1_2t = _interleaved_ms(
        [lambda: act(1), lambda: act(10), lambda: nocache(10), bf16(lambda: act(1)), bf16(lambda: act(10)),
         act_distinct, two_threads(lambda: act(1))], reps)
    out |= {"sample_ms_k1": k1, "sample_ms_k10": k10, "sample_ms_k10_nocache": k10_nocache,
            "sample_ms_k1_bf16": k1_bf16, "sample_ms_k10_bf16": k10_bf16,
            "sample_ms_k10_distinct_obs": k10_distinct, "sample_ms_k1_2threads": k1_2t}
    out["k10_over_k1"] = round(out["sample_ms_k10"] / out["sample_ms_k1"], 3)
    out["k10_over_k1_bf16"] = round(out["sample_ms_k10_bf16"] / out["sample_ms_k1_bf16"], 3)

    tcfg = TrainConfig()
    bf16 = native_bf16(tcfg.device) if tcfg.bf16 is None else tcfg.bf16  # what `seal train vla` would use here
    out["train_bf16"] = bf16
    step_s = train_step_s(cfg, batch=tcfg.batch_size, bf16=bf16, threads=tcfg.threads, reps=max(2, reps // 2))
    torch.set_num_threads(1)
    out["train_step_ms"] = round(1000 * step_s, 1)
    out["train_samples_per_s"] = round(tcfg.batch_size / step_s, 2)
    if getattr(args, "sizes", None):
        out["train_grid"] = [
            {"size": name, **SIZES[name], "params": count_parameters(VLAModel(_config(name, tok.vocab_size))),
             "tokens": _config(name, tok.vocab_size).total_tokens, "bf16": bf16, "threads": threads,
             "s_per_step": train_step_s(_config(name, tok.vocab_size), batch=tcfg.batch_size, bf16=bf16,
                                        threads=threads, reps=3)}
            for name in args.sizes.split(",") for threads in (1, 2) for bf16 in (True, False)]
        torch.set_num_threads(1)
    out["subplan_accuracy"] = out["action_mse"] = None
    if args.annotations:
        held = manifest.get("heldout_episodes")
        figures = heldout_eval(model, tok, Path(args.annotations), dataset=Path(args.dataset) if args.dataset else None,
                               episodes=held)
        out["subplan_accuracy"] = figures.get("subplan_accuracy")
        out["action_mse"] = figures["action_mse"]
        out["heldout"] = {"episodes": len(figures["heldout_episodes"]), "chunks": figures["eval_chunks"],
                          "split": "checkpoint manifest" if held else "trainer's seeded split"}
    else:
        out["heldout"] = "no --annotations given: subplan_accuracy and action_mse are null"
    if args.ckpt:  # does this machine drive the checkpoint the way the machine that shipped it did?
        out["reference_rollout"] = check_reference(str(path), record=bool(getattr(args, "record_reference", False)))
    if getattr(args, "rollouts", 0):
        from seal.policies.vla.locate import trained_render

        if not args.ckpt:
            raise InvalidInput("--rollouts needs --ckpt: a random-init model has nothing to show")
        trained = trained_render(str(path))
        render = args.render or trained["mode"]  # the mode its demonstrations were recorded in
        if not args.render and not trained["recorded"]:  # a guess: say so, the success rate depends on it
            out["rollout_render_note"] = (f"{path}'s manifest records no render mode; rolling out in "
                                          f"{render!r} (pass --render to choose)")
            print(f"seal: warning: {out['rollout_render_note']}", file=sys.stderr, flush=True)
        out |= rollouts(str(path), tasks=args.tasks, n=int(args.rollouts), render=render,
                        suite=getattr(args, "suite", None) or "libero_10", max_steps=getattr(args, "max_steps", None),
                        noise_scale=_noise_scale(args))
        if getattr(args, "round_log", None):
            out["round_plot"] = str(log_round(Path(args.round_log), args.round_name or str(path), out))
    return out


def _noise_scale(args) -> float:
    value = getattr(args, "noise_scale", None)  # 0 is a valid scale: no `or` default here
    return 1.0 if value is None else float(value)


def rollouts(ckpt: str, *, tasks: str, n: int, render: str, suite: str = "libero_10", max_steps: int | None = None,
             progress=None, noise_scale: float = 1.0) -> dict:
    """The policy alone, closed loop, on fresh sampled starts (see the module docstring)."""
    from seal.episode import run_policy_episode
    from seal.policies.vla.policy import VLAPolicy
    from seal.sim.suites import parse_task_ids, task_count
    from seal.sim.world import LiberoWorld

    if n < 1:
        raise InvalidInput(f"--rollouts must be >= 1, got {n}")
    progress = progress or (lambda line: print(line, file=sys.stderr, flush=True))  # stdout is the JSON
    ids = parse_task_ids(suite, tasks) if tasks else list(range(task_count(suite)))
    from seal.policies.vla.checkpoint import read_config
    from seal.policies.vla.locate import resolve_checkpoint

    if read_config(resolve_checkpoint(ckpt)).reasoning:  # labelled by the expert: on-policy reasoning figures too
        return _labelled_rollouts(ckpt, ids, n=n, render=render, suite=suite, max_steps=max_steps, progress=progress,
                                  noise_scale=noise_scale)
    policy = VLAPolicy.load(ckpt, noise_scale=noise_scale)
    rows = []
    for task_id in ids:
        world = LiberoWorld((suite, task_id), render_mode=render)
        try:
            for e in range(n):
                r = run_policy_episode(world, policy, init_index=ROLLOUT_EPISODE0 + e, max_steps=max_steps,
                                       start_seed=rollout_start_seed(world.task, e))
                held = list(r.goal_status.values())
                rows.append({"task": world.task.key, "start_seed": r.start_seed, "success": bool(r.success),
                             "subgoals": round(sum(held) / len(held), 3) if held else 0.0, "steps": r.steps,
                             "goal_status": r.goal_status})
                if progress:
                    progress(f"rollout {world.task.key} #{e}: success={r.success} "
                             f"subgoals={rows[-1]['subgoals']} steps={r.steps} ({r.wall_s:.0f} s)")
        finally:
            world.close()
    return {"rollout_success": round(float(np.mean([r["success"] for r in rows])), 3),
            "rollout_subgoals": round(float(np.mean([r["subgoals"] for r in rows])), 3),
            "rollout_suite": suite, "rollout_render": render, "noise_scale": noise_scale, "rollouts": rows}


def _labelled_rollouts(ckpt: str, ids: list[int], *, n: int, render: str, suite: str, max_steps: int | None,
                       progress, noise_scale: float = 1.0) -> dict:
    """The reasoning VLA alone on the same fresh starts, with the scripted expert reading every state it
    reaches (`seal.dagger`, beta 0: the expert never acts): success, sub-goals, and how its reasoning held
    up on its own states (sub-plan accuracy against the expert, alignment of the sub-plans it acted on)."""
    from seal.dagger import DaggerJob, release_cached, run_dagger_episode
    from seal.policies.vla.checkpoint import read_config
    from seal.policies.vla.locate import resolve_checkpoint
    from seal.sim.suites import get_task

    where = resolve_checkpoint(ckpt)
    size = read_config(where).image_size
    rows = []
    try:
        for task_id in ids:
            task = get_task(suite, task_id)
            key = task.key
            for e in range(n):
                job = DaggerJob(suite, task_id, ROLLOUT_EPISODE0 + e, 0, str(where), 0.0, render, size, max_steps,
                                start_seed=rollout_start_seed(task, e),
                                closed_loop=False,  # only the labels' text is scored here
                                noise_scale=noise_scale)
                _, a, _, _ = run_dagger_episode(job)
                rows.append({"task": key, "start_seed": a["start_seed"], "success": a["success"], "steps": a["steps"],
                             "subgoals": a["subgoals"],
                             "ended": a["ended"], "subplan_accuracy": a["subplan_accuracy"],
                             "alignment": a["alignment"], "committed": a["committed"],
                             "invalid_labels": a["invalid_labels"], "frames": a["frames"]})
                if progress:
                    progress(f"rollout {key} #{e}: success={a['success']} steps={a['steps']} ended={a['ended']} "
                             f"subplan_accuracy={a['subplan_accuracy']} alignment={a['alignment']}")
    finally:
        release_cached()
    frames = sum(r["frames"] for r in rows)
    committed = sum(r["committed"] for r in rows)
    return {"rollout_success": round(float(np.mean([r["success"] for r in rows])), 3),
            "rollout_subgoals": round(float(np.mean([r["subgoals"] for r in rows])), 3),
            # pooled over chunk boundaries / committed sub-plans, not averaged per episode
            "onpolicy_subplan_accuracy": round(sum(r["subplan_accuracy"] * r["frames"] for r in rows) / max(frames, 1), 4),
            "onpolicy_alignment": round(sum((r["alignment"] or 0) * r["committed"] for r in rows) / max(committed, 1), 4),
            "vla_done_early": sum(r["ended"] == "vla_done" for r in rows),
            "teacher_unanswered": round(sum(r["invalid_labels"] for r in rows) / max(frames, 1), 4),
            "rollout_suite": suite, "rollout_render": render, "noise_scale": noise_scale, "rollouts": rows}


REFERENCE = {"suite": "libero_10", "task": 5, "episode": 999, "steps": 40}  # a start no recording or rollout uses


def reference_rollout(ckpt: str) -> dict:
    """The VLA alone for ``REFERENCE["steps"]`` steps from one fixed fresh start, in the render model it
    was trained in: a digest of the executed actions (float32 bytes) and the reasoning it wrote, and the
    actions themselves (rounded) to say how far another machine is off when the digest differs."""
    import hashlib

    from seal.demos import start_seed
    from seal.episode import Recording, run_policy_episode
    from seal.policies.vla.locate import trained_render
    from seal.policies.vla.policy import VLAPolicy
    from seal.sim.world import LiberoWorld

    policy = VLAPolicy.load(ckpt)
    world = LiberoWorld((REFERENCE["suite"], REFERENCE["task"]), render_mode=trained_render(ckpt)["mode"])
    try:
        rec = Recording()
        r = run_policy_episode(world, policy, init_index=REFERENCE["episode"], max_steps=REFERENCE["steps"],
                               recording=rec, image_size=policy.image_size,
                               start_seed=start_seed(world.task.key, REFERENCE["episode"]))
    finally:
        world.close()
    actions = np.asarray(rec.actions, np.float32)
    h = hashlib.sha256(actions.tobytes())
    h.update("\n".join(t for _, t in r.reasoning).encode())
    return {**REFERENCE, "start_seed": r.start_seed, "digest": h.hexdigest()[:16], "executed": len(actions),
            "actions": np.round(actions.astype(np.float64), 5).tolist()}


def check_reference(ckpt: str, *, record: bool = False) -> dict:
    """This machine's reference rollout against the one the manifest records. ``record``: write this
    machine's into the manifest instead (what shipping a checkpoint does)."""
    import json

    from seal.checkpoint import MANIFEST, atomic_write
    from seal.policies.vla.locate import resolve_checkpoint

    where = resolve_checkpoint(ckpt)
    here = reference_rollout(ckpt)
    manifest = json.loads((where / MANIFEST).read_text())
    if record:
        manifest["reference_rollout"] = here
        atomic_write(where / MANIFEST, lambda p: p.write_text(json.dumps(manifest, indent=2) + "\n"))
        return {"recorded": True, "digest": here["digest"]}
    shipped = manifest.get("reference_rollout")
    if not shipped:
        return {"reproduced": None, "digest": here["digest"],
                "note": "the manifest records no reference rollout (seal bench vla --ckpt X --record-reference)"}
    a, b = np.asarray(here["actions"]), np.asarray(shipped["actions"])
    n = min(len(a), len(b))
    gap = np.abs(a[:n] - b[:n]).max(axis=1) if n else np.zeros(0)
    apart = np.flatnonzero(gap > 1e-3)
    return {"reproduced": here["digest"] == shipped["digest"], "digest": here["digest"],
            "manifest_digest": shipped["digest"], "max_abs_action_diff": round(float(gap.max()) if n else 0.0, 6),
            # the first executed step whose action differs by more than 1e-3 (None: never): how soon it drifts
            "first_step_apart": int(apart[0]) if len(apart) else None}


def redraw_rounds(log: str | None, names: list[str] | None = None, out: str | None = None) -> dict:
    """`seal bench vla --round-log LOG --redraw [--round NAME ...] [--plot PNG]`: the per-round plot drawn
    again from the log alone; ``names`` picks rows (in that order), ``out`` writes elsewhere than LOG.png."""
    import json

    from seal.report.plots import rounds_plot

    if not log or not Path(log).is_file():
        raise InvalidInput(f"--redraw needs --round-log naming an existing log (a `seal bench vla --rollouts` "
                           f"output); got {log!r}")
    rows = [json.loads(line) for line in Path(log).read_text().splitlines() if line.strip()]
    if not rows:
        raise InvalidInput(f"{log} holds no rounds yet")
    if names:
        by_name = {r["round"]: r for r in rows}
        unknown = [n for n in names if n not in by_name]
        if unknown:
            raise InvalidInput(f"--round {unknown[0]!r} is not in {log}; its rounds: "
                               + "; ".join(repr(n) for n in by_name))
        rows = [by_name[n] for n in names]
    path = Path(out) if out else Path(log).with_suffix(".png")
    return {"round_log": str(log), "rounds": len(rows), "round_plot": str(rounds_plot(rows, path))}


def log_round(log: Path, name: str, out: dict) -> Path:
    """Append this bench's held-out rollout figures as round ``name`` to ``log`` (JSONL; a round of the
    same name is replaced) and redraw the per-round plot beside it (``log`` with .png)."""
    import json

    from seal.report.plots import rounds_plot

    row = {"round": name, "ckpt": out.get("ckpt"), "suite": out.get("rollout_suite"), "episodes": len(out["rollouts"]),
           **{k: out.get(k) for k in ("rollout_success", "rollout_subgoals", "onpolicy_subplan_accuracy",
                                      "onpolicy_alignment", "vla_done_early", "teacher_unanswered", "noise_scale")}}
    rows = [json.loads(line) for line in log.read_text().splitlines() if line.strip()] if log.is_file() else []
    rows = [r for r in rows if r["round"] != name] + [row]
    log.parent.mkdir(parents=True, exist_ok=True)
    log.write_text("".join(json.dumps(r) + "\n" for r in rows))
    return rounds_plot(rows, log.with_suffix(".png"))
