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
- ``train_samples_per_s``: training throughput at batch 32 with the default `TrainConfig`
  (bf16 autocast, one thread), on a synthetic batch of the real shapes;
- ``subplan_accuracy`` / ``action_mse``: `seal.train.vla.evaluate` on held-out episodes (the
  checkpoint manifest's, else the trainer's split) when --annotations is given; else null.

Timings are medians of ``--trials`` repetitions (default 5) with one torch thread.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np


def _median_ms(fn, reps: int) -> float:
    fn()  # warm-up (allocator, lazy init)
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return round(1000 * float(np.median(times)), 2)


def run(args) -> dict:
    import torch

    from seal.policies.base import Reasoning
    from seal.policies.vla.checkpoint import load_checkpoint
    from seal.policies.vla.locate import resolve_checkpoint
    from seal.policies.vla.model import VLAConfig, VLAModel, count_parameters
    from seal.policies.vla.policy import VLAPolicy
    from seal.policies.vla.tokenizer import project_texts, train_tokenizer
    from seal.sim.observation import Observation
    from seal.train.vla import TrainConfig, heldout_eval, synthetic_batch

    torch.set_num_threads(1)
    reps = getattr(args, "trials", None) or 5
    out: dict = {}
    if args.ckpt:
        path = resolve_checkpoint(args.ckpt)
        model, tok, manifest = load_checkpoint(path)
        out |= {"weights": "checkpoint", "ckpt": str(path)}
    else:
        tok = train_tokenizer(project_texts())
        torch.manual_seed(0)
        model, manifest = VLAModel(VLAConfig(vocab_size=tok.vocab_size)).eval(), {}
        out |= {"weights": "random-init"}
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
        out["reason_tokens"] = len(tok.encode(policy.last_text))
    else:
        out["reason_ms"] = None  # the twin writes no reasoning

    def act(k: int):
        policy.begin(k)
        return policy.act([obs] * k, reasoning)

    def nocache(k: int):
        policy.begin(k)
        return [policy.act([obs], reasoning, rows=[r]) for r in range(k)]

    out["sample_ms_k1"] = _median_ms(lambda: act(1), reps)
    out["sample_ms_k10"] = _median_ms(lambda: act(10), reps)
    out["sample_ms_k10_nocache"] = _median_ms(lambda: nocache(10), max(1, reps // 2))
    out["k10_over_k1"] = round(out["sample_ms_k10"] / out["sample_ms_k1"], 3)

    tcfg = TrainConfig()
    trainee = VLAModel(cfg).train()
    opt = torch.optim.AdamW(trainee.parameters(), lr=1e-4)
    batch = synthetic_batch(cfg, tcfg.batch_size)
    gen = torch.Generator().manual_seed(0)

    def step():
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=tcfg.bf16):
            loss, _ = trainee.loss(batch, gen)
        opt.zero_grad()
        loss.backward()
        opt.step()

    out["train_step_ms"] = _median_ms(step, max(2, reps // 2))
    out["train_samples_per_s"] = round(tcfg.batch_size / (out["train_step_ms"] / 1000), 2)
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
    return out
