"""`VLAPolicy`: a trained VLA checkpoint behind SEAL's `ReasoningPolicy` seam.

Inputs are what a real VLA gets: both camera images, the 8-d proprio state and the prompt of
each `Observation`; ``privileged_atoms()`` is None, so the loop never hands it a `SceneState`.

- ``reason(obs)``: greedy decoding of ``<think> ... <act>`` over the cached prefix, parsed into a
  `Reasoning`. A text that does not parse fully keeps what it can (at least the "Now I need to
  do" field; the raw text is kept in ``last_text``), so a half-trained model still acts.
- ``begin(k)``: k attempts; row r draws its flow noise from its own generator seeded by
  (policy seed, episode seed, attempt number, r), so a row's chunks do not depend on which other
  rows are still active.
- ``act(obs_batch, reasoning, rows)``: rows that show the same observation (all K candidates at
  the start of a round) share one prefix + reasoning encode, whose expert keys/values serve all
  K noise draws without being copied; rows with their own observation (later chunks) are
  encoded together as one batch. Each row gets
  a (16, 7) chunk in [-1, 1] and ``think`` from the learned head (p > 0.5), except on a row's first
  chunk of an attempt: the model has just written ``<act>`` for that observation, and in pi0-reason's
  grammar a chunk follows every ``<act>``. Without this rule a reasoning text the think head judged
  stale made the model think again before acting, greedy decoding of the unchanged observation wrote
  the same text, and the loop's idle guard ended the episode: in the first LIBERO-10 evaluation of the
  reasoning VLA 52 of 93 failed episodes ended before the step limit, 15 of 92 with this rule
  (docs/results.md).

The non-reasoning twin (config ``reasoning=False``, the pi0 baseline) cannot write sub-plans and
declares ``thinks = False``: the steering loop then ends its sub-plans by the verifier's
mid-rollout checks or the step budget, as for a plain pi0 server. Its sub-plans come from the
method's planner when one is set (``--planner annotations|vlm``, as for `remote`); otherwise the
whole instruction is its one sub-plan (``Reasoning(plans=(instruction,), now=instruction)``),
which is what pi0 is asked to do. The twin is prompted with the instruction, as it was trained.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from seal.errors import InvalidInput, PolicyError
from seal.policies.base import PREDICT_HORIZON, ActionChunk, Reasoning, parse_lenient
from seal.policies.vla.checkpoint import load_checkpoint
from seal.policies.vla.locate import resolve_checkpoint
from seal.policies.vla.model import ACTION_DIM, VLAModel
from seal.policies.vla.preprocess import instruction_ids, reasoning_ids, resize_images
from seal.policies.vla.tokenizer import VLATokenizer
from seal.sim.observation import Observation


class VLAPolicy:
    def __init__(self, model: VLAModel, tokenizer: VLATokenizer, *, seed: int = 0, planner=None,
                 instruction: str = "", source: str = "", manifest: dict | None = None, bf16: bool = False,
                 noise_scale: float = 1.0):
        if not (noise_scale >= 0.0 and np.isfinite(noise_scale)):
            raise InvalidInput(f"noise_scale must be a finite number >= 0, got {noise_scale}")
        self.model = model.eval()
        self.tok = tokenizer
        self.cfg = model.cfg
        self.thinks = self.cfg.reasoning
        # both cameras rendered at the size the model was trained at (the steering loop reads this)
        self.image_size = self.cfg.image_size
        self.planner = planner
        self.source = source
        self.manifest = manifest or {}
        self.seed = seed
        # bf16 autocast for `act` (the network as trained, the Euler sum in fp32): cheaper per extra
        # candidate on CPUs with bf16 units; off by default, fp32 is the reference
        self.bf16 = bf16
        # the flow's starting noise is drawn from N(0, noise_scale^2): 1 is the distribution the model was
        # trained to transport; below 1 pulls every draw toward the chunk reached from zero noise, which
        # for a single sample (the policy alone) trades diversity for the most central chunk. SEAL's K
        # candidates need the diversity: keep 1 there.
        self.noise_scale = float(noise_scale)
        self.last_text = ""  # the last raw reasoning text the model wrote
        self.last_tokens = 0  # and its length in tokens
        self._instruction = instruction  # the prompt of observations that carry none
        self._episode_seed = 0
        self._attempts = 0
        self._gens: list[torch.Generator] = []
        self._chunks: list[int] = []
        self._ids: dict[str, tuple[np.ndarray, np.ndarray, int]] = {}

    @classmethod
    def load(cls, path: str | Path = "", *, seed: int = 0, device: str = "cpu", planner=None,
             instruction: str = "", threads: int | None = 1, noise_scale: float = 1.0) -> VLAPolicy:
        """``threads``: torch's intra-op threads (process-wide; None leaves them). One by default: on
        the 2-core machine shared with simulator workers, two threads cost many times more per chunk
        (`seal bench vla`: sample_ms_k1_2threads against sample_ms_k1, docs/performance.md)."""
        if threads is not None and device == "cpu":
            torch.set_num_threads(int(threads))
        where = resolve_checkpoint(str(path))
        model, tok, manifest = load_checkpoint(where, device=device)
        return cls(model, tok, seed=seed, planner=planner, instruction=instruction, source=str(where),
                   manifest=manifest, noise_scale=noise_scale)

    # -- protocol ---------------------------------------------------------------------------------
    def close(self) -> None:
        return None

    def privileged_atoms(self) -> list[str] | None:
        return None

    def reset(self, instruction: str, seed: int) -> None:
        self._instruction = instruction
        self._episode_seed = int(seed)
        self._attempts = 0
        self._gens = []
        self._chunks = []
        if self.planner is not None:
            self.planner.reset(instruction)

    @torch.inference_mode()
    def reason(self, obs: Observation) -> Reasoning:
        instruction = obs.prompt or self._instruction
        if not self.cfg.reasoning:
            if self.planner is not None:
                return self.planner.next(obs)
            return Reasoning(plans=(instruction,), done=(), now=instruction)
        prefix = self.encode([obs])
        self.last_text = self.decode(prefix)
        return parse_lenient(self.last_text, instruction)

    def begin(self, k: int) -> None:
        if k < 1:
            raise InvalidInput(f"begin needs k >= 1, got {k}")
        self._attempts += 1
        self._chunks = [0] * k  # chunks each row has been given in this attempt
        self._gens = [torch.Generator().manual_seed(int(np.random.SeedSequence(
            [self.seed, self._episode_seed, self._attempts, row]).generate_state(1)[0])) for row in range(k)]

    @torch.inference_mode()
    def act(self, obs_batch: Sequence[Observation], reasoning: Reasoning,
            rows: Sequence[int] | None = None) -> list[ActionChunk]:
        if not obs_batch:
            return []
        rows = list(range(len(obs_batch))) if rows is None else list(rows)
        if len(rows) != len(obs_batch):
            raise InvalidInput(f"act got {len(obs_batch)} observations but {len(rows)} rows")
        if not self._gens:
            self.begin(max(rows) + 1)
        if max(rows) >= len(self._gens):
            raise InvalidInput(f"row {max(rows)} was not started; begin({len(self._gens)}) was called")
        # one prefix per distinct observation; rows showing the same one share it
        keys = [_obs_key(o) for o in obs_batch]
        unique = list(dict.fromkeys(keys))
        # scaled after the draw, so a row's random stream is the same at every scale (x 1.0 is exact)
        noise = self.noise_scale * torch.stack([torch.randn(PREDICT_HORIZON, ACTION_DIM, generator=self._gens[r])
                                                for r in rows])
        with torch.autocast(self.model.device.type, dtype=torch.bfloat16, enabled=self.bf16):
            cond = self.condition([obs_batch[keys.index(k)] for k in unique], reasoning)
            index = [unique.index(k) for k in keys]
            if len(unique) > 1 and index != list(range(len(unique))):
                cond = cond.select(torch.tensor(index, device=self.model.device))
            # (one distinct observation: the one-row condition serves every row as it is)
            actions = self.model.sample_actions(cond, noise.to(self.model.device)).float()
        actions = actions.clamp(-1.0, 1.0).cpu().numpy()
        if not np.isfinite(actions).all():  # NaN survives the clamp; a world must never execute it
            raise PolicyError(f"the VLA ({self.source or 'in memory'}) produced non-finite actions; its weights or "
                              f"inputs are broken (state finite: {all(np.isfinite(o.state).all() for o in obs_batch)})")
        think = ([False] * len(rows) if cond.think_logit is None
                 else (torch.sigmoid(cond.think_logit.float()) > 0.5).expand(len(rows)).cpu().tolist())
        think = [bool(t) and self._chunks[r] > 0 for t, r in zip(think, rows)]  # first chunk: just wrote <act>
        for r in rows:
            self._chunks[r] += 1
        return [ActionChunk(actions=a.astype(np.float32), think=bool(t)) for a, t in zip(actions, think)]

    # -- building blocks (also used by `seal bench vla` and the trainer's evaluation) ---------------
    def _inputs(self, obs_batch: Sequence[Observation], instruction: bool = True) -> dict[str, torch.Tensor]:
        size, dev = self.cfg.image_size, self.model.device
        for o in obs_batch:
            if o.agent is None or o.wrist is None:
                raise InvalidInput("the VLA needs both camera images; observe with images=True")
        agent = np.stack([resize_images(o.agent, size) for o in obs_batch])  # sizes may differ per row
        wrist = np.stack([resize_images(o.wrist, size) for o in obs_batch])
        prompts = [(o.prompt or self._instruction) if instruction else "" for o in obs_batch]
        ids = [instruction_ids(self.tok, p, self.cfg.max_instruction_tokens) for p in prompts]
        return {"agent": torch.from_numpy(agent).to(dev), "wrist": torch.from_numpy(wrist).to(dev),
                "state": torch.as_tensor(np.stack([np.asarray(o.state, np.float32) for o in obs_batch])).to(dev),
                "instr_ids": torch.from_numpy(np.stack([i for i, _ in ids])).to(dev),
                "instr_valid": torch.from_numpy(np.stack([v for _, v in ids])).to(dev)}

    def encode(self, obs_batch: Sequence[Observation], instruction: bool = True):
        """The prefix (images, state, instruction) of each observation, as one batch; ``instruction=False``
        leaves the instruction empty (the action prefix of a model whose actions follow the plan alone)."""
        x = self._inputs(obs_batch, instruction)
        return self.model.encode_prefix(x["agent"], x["wrist"], x["state"], x["instr_ids"], x["instr_valid"])

    def decode(self, prefix) -> str:
        """Greedy decoding of one row's reasoning after ``prefix`` (its KV cache grows by one
        token per step; nothing before is recomputed)."""
        model, dev = self.model, self.model.device
        one = torch.ones(1, 1, dtype=torch.bool, device=dev)
        seq = model.extend(prefix, torch.tensor([[self.tok.think_id]], device=dev), one)
        out: list[int] = []
        for _ in range(self.cfg.max_reasoning_tokens - 2):
            nxt = int(model.text_logits(seq.hidden[:, -1]).argmax(-1))
            if nxt in (self.tok.act_id, self.tok.eos_id, self.tok.pad_id):
                break
            out.append(nxt)
            seq = model.extend(seq, torch.tensor([[nxt]], device=dev), one)
        self.last_tokens = len(out)
        return self.tok.decode(out)

    def condition(self, obs_batch: Sequence[Observation], reasoning: Reasoning | None):
        """Prefix (+ the reasoning, teacher-forced) of each observation -> the expert's condition."""
        seq = self.encode(obs_batch, instruction=self.cfg.actions_read_instruction)
        if not self.cfg.reasoning:
            return self.model.condition(seq)
        text = reasoning.text() if reasoning is not None else ""
        if text not in self._ids:
            self._ids = {text: reasoning_ids(self.tok, text, self.cfg.max_reasoning_tokens)}  # one text at a time
        ids, valid, act = self._ids[text]
        n, dev = len(obs_batch), self.model.device
        ids, valid = ids[: act + 1], valid[: act + 1]  # no padding at inference: same result, shorter memory
        seq = self.model.extend(seq, torch.from_numpy(ids).to(dev)[None].expand(n, -1),
                                torch.from_numpy(valid).to(dev)[None].expand(n, -1))
        return self.model.condition(seq, torch.full((n,), self.cfg.prefix_tokens + act, device=dev))


def _obs_key(o: Observation) -> tuple:
    state = np.asarray(o.state, np.float32)
    agent, wrist = np.asarray(o.agent), np.asarray(o.wrist)
    return (o.prompt, state.tobytes(), hash(agent.tobytes()), hash(wrist.tobytes()))


def vla_policy(spec, task, *, seed: int = 0) -> VLAPolicy:
    """`seal.policies.make_policy`'s ``vla`` entry: the checkpoint named by ``spec.policy_ckpt``
    (default: the shipped reasoning model; ``twin`` for the shipped twin), and for a twin the
    method's planner when one is set."""
    planner = None
    if spec.planner:
        from seal.policies.planners import make_planner

        planner = make_planner(spec.planner, spec=task, annotations=spec.annotations, model=spec.planner_model,
                               base_url=spec.base_url)
    policy = VLAPolicy.load(spec.policy_ckpt, seed=seed, planner=planner, instruction=task.instruction,
                            noise_scale=spec.noise_scale)
    if policy.cfg.reasoning and planner is not None:
        raise InvalidInput("a reasoning VLA writes its own sub-plans; --planner is for the non-reasoning twin")
    return policy
