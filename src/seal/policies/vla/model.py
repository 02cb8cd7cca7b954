"""The learned reasoning VLA: pi0's structure, scaled down to what a 2-core CPU trains in hours.

    agent view  ─ conv encoder ─┐
    wrist view  ─ conv encoder ─┤  prefix: bidirectional attention among
    state (8)   ─ linear ───────┤  image, state and instruction tokens
    instruction ─ embedding ────┘
                                   reasoning: <think> Plans: ... Now I need to do: ... <act>
                                   causal (each token sees the prefix and the tokens before it);
                                   next-token cross-entropy, and a `think` logit read at <act>
    action expert: 16 noisy action tokens + flow time; self-attention among them, cross-attention
                   to the backbone's output over prefix + reasoning (keys/values computed once);
                   predicts the flow velocity (pi0's flow matching)

Sequence layout (fixed segment lengths, so positions mean the same in training and inference):

    [agent P][wrist P][state 1][instruction L_i, <bos> first, padded][reasoning L_r, padded]

with P = (image_size / patch)^2. The total must fit the 415-token budget of the paper's
Table I. The backbone is a prefix-LM: since prefix tokens never attend to reasoning tokens,
their keys/values are computed once and reused (a KV cache) when the reasoning is decoded token
by token, and training runs the very same two calls (`encode_prefix`, then `extend` with the
reasoning) so that the cached inference path and the trained path are one code path.

Flow matching (pi0, Black et al. 2024): with actions a and Gaussian noise e, the path is
x_t = t * e + (1 - t) * a for t in [0, 1] (t = 1 is pure noise); the expert regresses the
velocity u = e - a. Training draws t from Beta(1.5, 1) (more weight near the noisy end, as pi0
does), by inverse CDF so that a seeded generator reproduces it; inference integrates from
t = 1 to 0 with ``flow_steps`` Euler steps.

With ``actions_read_instruction=False`` the expert's condition is computed from a second prefix whose
instruction is empty: the reasoning is still written from the instruction, but the chunk (and the
`think` flag) follow from the pixels, the state and the sub-plan text alone.

The non-reasoning twin (``reasoning=False``, the pi0 baseline) is the same network without the
reasoning segment: no text loss, no think head; the expert attends to the prefix only.

Actions and states are normalised with dataset statistics stored as buffers, so a checkpoint
carries them. Nothing here is CPU-specific: every call takes tensors on the model's device.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import torch
from torch import nn
from torch.nn import functional as F

from seal.errors import InvalidInput
from seal.policies.base import PREDICT_HORIZON

STATE_DIM = 8
ACTION_DIM = 7
TOKEN_BUDGET = 415  # max tokens of one sequence (the paper's Table I)


@dataclass(frozen=True)
class VLAConfig:
    """Everything that shapes the network (saved as config.json beside the weights)."""

    # Defaults: chosen by measurement on this 2-core CPU (docs/performance.md, "Learned VLA"):
    # ~9k training steps at batch 32 in about 3 hours, and 10 candidate chunks within 150 ms.
    vocab_size: int = 1024
    image_size: int = 64  # both cameras, square, uint8 RGB in openpi's orientation
    patch: int = 16  # conv downsampling factor: (image_size / patch)^2 tokens per camera
    d_model: int = 256
    n_heads: int = 4
    n_layers: int = 4  # backbone (prefix + reasoning)
    d_expert: int = 128
    expert_heads: int = 4
    expert_layers: int = 2
    mlp_ratio: int = 4
    expert_mlp_ratio: int = 2  # the expert runs K x 16 tokens x flow_steps at inference: kept lean
    max_instruction_tokens: int = 32  # <bos> + instruction
    max_reasoning_tokens: int = 112  # <think> + reasoning + <act> (LIBERO-10/90 labels: at most 94)
    horizon: int = PREDICT_HORIZON
    reasoning: bool = True  # False: the non-reasoning twin (pi0 baseline)
    # False: the action expert (and the think flag read beside it) sees the prefix with an empty
    # instruction, so a chunk depends on the cameras, the state and the sub-plan text alone. A reworded
    # instruction then changes the actions only through the plan the model wrote for it (issue 31).
    actions_read_instruction: bool = True
    text_weight: float = 0.5
    action_weight: float = 0.5
    think_weight: float = 0.1
    flow_steps: int = 10

    def __post_init__(self) -> None:
        if self.image_size % self.patch or self.patch & (self.patch - 1) or self.patch < 2:
            raise InvalidInput(f"patch must be a power of two >= 2 dividing image_size; got patch={self.patch}, "
                               f"image_size={self.image_size}")
        if not self.reasoning and not self.actions_read_instruction:
            raise InvalidInput("actions_read_instruction=False needs a reasoning model: without a sub-plan the "
                               "twin's actions would have nothing that names the task")
        if self.d_model % self.n_heads or self.d_expert % self.expert_heads:
            raise InvalidInput("d_model and d_expert must be multiples of their head counts")
        if self.total_tokens > TOKEN_BUDGET:
            raise InvalidInput(f"sequence of {self.total_tokens} tokens exceeds the {TOKEN_BUDGET}-token budget "
                               f"(images {2 * self.image_tokens}, state 1, instruction {self.max_instruction_tokens}, "
                               f"reasoning {self.reasoning_tokens})")

    @property
    def image_tokens(self) -> int:
        return (self.image_size // self.patch) ** 2

    @property
    def prefix_tokens(self) -> int:
        return 2 * self.image_tokens + 1 + self.max_instruction_tokens

    @property
    def reasoning_tokens(self) -> int:
        return self.max_reasoning_tokens if self.reasoning else 0

    @property
    def total_tokens(self) -> int:
        return self.prefix_tokens + self.reasoning_tokens

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> VLAConfig:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise InvalidInput(f"unknown VLA config field(s) {unknown}; known: {sorted(known)}")
        return cls(**d)


# ---------------------------------------------------------------------------------- building blocks


def _heads(x: torch.Tensor, h: int) -> torch.Tensor:
    b, s, d = x.shape
    return x.view(b, s, h, d // h).transpose(1, 2)  # (B, H, S, dh)


def _merge(x: torch.Tensor) -> torch.Tensor:
    b, h, s, dh = x.shape
    return x.transpose(1, 2).reshape(b, s, h * dh)


class SelfAttention(nn.Module):
    def __init__(self, d: int, heads: int):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(d, 3 * d)
        self.out = nn.Linear(d, d)

    def forward(self, x, mask, past=None):
        """``mask``: bool (B, 1, Sq, Sk), True = may attend; ``past``: cached (k, v) to prepend.
        Returns the output and the (k, v) of every key so far (the cache to keep)."""
        q, k, v = (_heads(t, self.heads) for t in self.qkv(x).chunk(3, dim=-1))
        if past is not None:
            k, v = torch.cat([past[0], k], dim=2), torch.cat([past[1], v], dim=2)
        y = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
        return self.out(_merge(y)), (k, v)


class CrossAttention(nn.Module):
    """Queries from the action tokens, keys/values from the backbone's output (``memory``)."""

    def __init__(self, d: int, heads: int, d_memory: int):
        super().__init__()
        self.heads = heads
        self.q = nn.Linear(d, d)
        self.kv = nn.Linear(d_memory, 2 * d)
        self.out = nn.Linear(d, d)

    def memory_kv(self, memory):
        k, v = self.kv(memory).chunk(2, dim=-1)
        return _heads(k, self.heads), _heads(v, self.heads)

    def forward(self, x, kv, mask):
        b, n, d = x.shape
        if kv[0].shape[0] == 1 and b > 1:
            # K candidates over one shared memory: each query attends independently, so the K rows
            # are laid end to end as one row of K*n queries against the single copy of the keys
            # and values (no per-step copy of the memory K times over).
            y = F.scaled_dot_product_attention(_heads(self.q(x).reshape(1, b * n, d), self.heads), kv[0], kv[1],
                                               attn_mask=mask)
            return self.out(_merge(y)).reshape(b, n, d)
        y = F.scaled_dot_product_attention(_heads(self.q(x), self.heads), kv[0], kv[1], attn_mask=mask)
        return self.out(_merge(y))


def _mlp(d: int, ratio: int) -> nn.Module:
    return nn.Sequential(nn.Linear(d, ratio * d), nn.GELU(), nn.Linear(ratio * d, d))


class Block(nn.Module):
    """Pre-norm transformer block of the backbone."""

    def __init__(self, d: int, heads: int, ratio: int):
        super().__init__()
        self.ln1, self.ln2 = nn.LayerNorm(d), nn.LayerNorm(d)
        self.attn = SelfAttention(d, heads)
        self.mlp = _mlp(d, ratio)

    def forward(self, x, mask, past=None):
        h, kv = self.attn(self.ln1(x), mask, past)
        x = x + h
        return x + self.mlp(self.ln2(x)), kv


class ExpertBlock(nn.Module):
    def __init__(self, d: int, heads: int, d_memory: int, ratio: int):
        super().__init__()
        self.ln1, self.ln2, self.ln3 = nn.LayerNorm(d), nn.LayerNorm(d), nn.LayerNorm(d)
        self.attn = SelfAttention(d, heads)
        self.cross = CrossAttention(d, heads, d_memory)
        self.mlp = _mlp(d, ratio)

    def forward(self, x, kv, mask):
        x = x + self.attn(self.ln1(x), None)[0]  # the 16 action tokens see each other
        x = x + self.cross(self.ln2(x), kv, mask)
        return x + self.mlp(self.ln3(x))


class ConvEncoder(nn.Module):
    """(B, H, W, 3) uint8 -> (B, (H/patch)^2, d) tokens: stride-2 conv stages, trained from scratch
    (no pretrained vision weights can reach this machine). One encoder serves both cameras, as
    pi0's SigLIP does; a learned camera embedding tells them apart."""

    def __init__(self, cfg: VLAConfig):
        super().__init__()
        stages, ch_in, ch = [], 3, 32
        for _ in range(int(math.log2(cfg.patch))):
            stages += [nn.Conv2d(ch_in, ch, 3, stride=2, padding=1), nn.GroupNorm(8, ch), nn.GELU()]
            ch_in, ch = ch, min(2 * ch, 256)
        self.conv = nn.Sequential(*stages, nn.Conv2d(ch_in, cfg.d_model, 1))
        self.camera = nn.Parameter(torch.zeros(2, 1, cfg.d_model))

    def forward(self, images: torch.Tensor, camera: int) -> torch.Tensor:
        x = images.permute(0, 3, 1, 2).float().div(127.5).sub(1.0)
        y = self.conv(x).flatten(2).transpose(1, 2)  # (B, P, d), row-major patches
        return y + self.camera[camera]


def time_embedding(t: torch.Tensor, dim: int) -> torch.Tensor:
    """Sine-cosine features of the flow time t in [0, 1] (periods 4e-3 .. 4, as in pi0)."""
    half = dim // 2
    period = 4e-3 * (4.0 / 4e-3) ** torch.linspace(0.0, 1.0, half, device=t.device)
    angle = t[:, None].float() * (2 * math.pi / period)[None]
    return torch.cat([torch.sin(angle), torch.cos(angle)], dim=-1)


class ActionExpert(nn.Module):
    def __init__(self, cfg: VLAConfig):
        super().__init__()
        d = cfg.d_expert
        self.dim = d
        self.action_in = nn.Linear(ACTION_DIM, d)
        self.time_mix = nn.Sequential(nn.Linear(2 * d, d), nn.SiLU(), nn.Linear(d, d))  # pi0's action-time MLP
        self.pos = nn.Parameter(torch.randn(cfg.horizon, d) * 0.02)
        self.blocks = nn.ModuleList(ExpertBlock(d, cfg.expert_heads, cfg.d_model, cfg.expert_mlp_ratio)
                                    for _ in range(cfg.expert_layers))
        self.ln = nn.LayerNorm(d)
        self.out = nn.Linear(d, ACTION_DIM)

    def memory_kv(self, memory: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Each block's cross-attention keys/values of the memory: computed once per prefix and
        reused by every Euler step and every candidate."""
        return [b.cross.memory_kv(memory) for b in self.blocks]

    def forward(self, x_t, t, kv, mask):
        """Velocity at (x_t, t): x_t (B, horizon, 7) normalised actions, t (B,)."""
        a = self.action_in(x_t)
        te = time_embedding(t, self.dim).to(a.dtype)[:, None].expand_as(a)
        h = self.time_mix(torch.cat([a, te], dim=-1)) + self.pos
        for block, layer_kv in zip(self.blocks, kv):
            h = block(h, layer_kv, mask)
        return self.out(self.ln(h))


# ---------------------------------------------------------------------------------- the model


@dataclass
class Prefix:
    """The backbone's state after some tokens: per-layer keys/values (the cache), final hidden
    states of every token so far (the action expert's memory) and which of them are real."""

    kv: list[tuple[torch.Tensor, torch.Tensor]]
    hidden: torch.Tensor  # (B, S, d), after the final layer norm
    valid: torch.Tensor  # (B, S) bool

    @property
    def length(self) -> int:
        return self.hidden.shape[1]


@dataclass
class Condition:
    """What the action expert and the think head need for a batch of rows. A condition of one row
    serves any number of candidates: its keys/values are shared, never copied (`CrossAttention`)."""

    kv: list[tuple[torch.Tensor, torch.Tensor]]  # per expert block, cross-attention keys/values
    mask: torch.Tensor  # (B, 1, 1, S) bool
    think_logit: torch.Tensor | None  # (B,), None for the twin

    @property
    def rows(self) -> int:
        return self.mask.shape[0]

    def select(self, index: torch.Tensor) -> Condition:
        """Rows ``index`` (a row may repeat); copies, once per call, not per Euler step."""
        return Condition([(a[index], b[index]) for a, b in self.kv], self.mask[index],
                         None if self.think_logit is None else self.think_logit[index])


class VLAModel(nn.Module):
    def __init__(self, cfg: VLAConfig):
        super().__init__()
        self.cfg = cfg
        d = cfg.d_model
        self.vision = ConvEncoder(cfg)
        self.tokens = nn.Embedding(cfg.vocab_size, d)  # also the text head (tied weights)
        self.state_in = nn.Linear(STATE_DIM, d)
        self.pos = nn.Parameter(torch.randn(cfg.total_tokens, d) * 0.02)
        self.blocks = nn.ModuleList(Block(d, cfg.n_heads, cfg.mlp_ratio) for _ in range(cfg.n_layers))
        self.ln = nn.LayerNorm(d)
        if cfg.reasoning:
            self.think_head = nn.Sequential(nn.Linear(d, d), nn.GELU(), nn.Linear(d, 1))
        self.expert = ActionExpert(cfg)
        # dataset statistics (set by the trainer, saved with the weights)
        self.register_buffer("state_mean", torch.zeros(STATE_DIM))
        self.register_buffer("state_std", torch.ones(STATE_DIM))
        self.register_buffer("action_mean", torch.zeros(ACTION_DIM))
        self.register_buffer("action_std", torch.ones(ACTION_DIM))
        self.apply(self._init)

    @staticmethod
    def _init(m: nn.Module) -> None:
        if isinstance(m, (nn.Linear, nn.Embedding)):
            nn.init.normal_(m.weight, std=0.02)
            if getattr(m, "bias", None) is not None:
                nn.init.zeros_(m.bias)

    @property
    def device(self) -> torch.device:
        return self.pos.device

    def set_normalization(self, state_mean, state_std, action_mean, action_std) -> None:
        for name, value in (("state_mean", state_mean), ("state_std", state_std), ("action_mean", action_mean),
                            ("action_std", action_std)):
            value = torch.as_tensor(value, dtype=torch.float32)
            if name.endswith("std"):
                value = value.clamp_min(1e-2)  # a constant dimension (e.g. unused rotation) stays finite
            getattr(self, name).copy_(value)

    # -- backbone ---------------------------------------------------------------------------------
    def encode_prefix(self, agent, wrist, state, instr_ids, instr_valid) -> Prefix:
        """Images (B, H, W, 3) uint8, state (B, 8), instruction ids/valid (B, L_i) -> Prefix.
        Prefix tokens attend to each other both ways (pi0's prefix)."""
        cfg = self.cfg
        if instr_ids.shape[1] != cfg.max_instruction_tokens:
            raise InvalidInput(f"instruction ids must be padded to {cfg.max_instruction_tokens}, got {instr_ids.shape[1]}")
        s = ((state.float() - self.state_mean) / self.state_std)[:, None]
        x = torch.cat([self.vision(agent, 0), self.vision(wrist, 1), self.state_in(s), self.tokens(instr_ids)], dim=1)
        x = x + self.pos[: x.shape[1]]
        b = x.shape[0]
        valid = torch.cat([torch.ones(b, 2 * cfg.image_tokens + 1, dtype=torch.bool, device=x.device),
                           instr_valid.bool()], dim=1)
        mask = valid[:, None, None, :]
        kv = []
        for block in self.blocks:
            x, layer_kv = block(x, mask)
            kv.append(layer_kv)
        return Prefix(kv, self.ln(x), valid)

    def extend(self, prefix: Prefix, ids: torch.Tensor, valid: torch.Tensor) -> Prefix:
        """Run reasoning tokens (B, L) after ``prefix``: each attends to the prefix and causally to
        the tokens before it. One token at a time (greedy decoding) or all at once (training,
        teacher forcing) give the same result."""
        start, n = prefix.length, ids.shape[1]
        if start + n > self.cfg.total_tokens:
            raise InvalidInput(f"sequence would be {start + n} tokens, longer than {self.cfg.total_tokens}")
        x = self.tokens(ids) + self.pos[start:start + n]
        causal = torch.ones(n, n, dtype=torch.bool, device=x.device).tril()
        mask = torch.cat([prefix.valid[:, None, None, :].expand(-1, 1, n, -1),
                          causal[None, None] & valid.bool()[:, None, None, :]], dim=-1)
        kv = []
        for block, past in zip(self.blocks, prefix.kv):
            x, layer_kv = block(x, mask, past)
            kv.append(layer_kv)
        return Prefix(kv, torch.cat([prefix.hidden, self.ln(x)], dim=1),
                      torch.cat([prefix.valid, valid.bool()], dim=1))

    def text_logits(self, hidden: torch.Tensor) -> torch.Tensor:
        return hidden @ self.tokens.weight.t()

    def condition(self, seq: Prefix, act_pos: torch.Tensor | None = None) -> Condition:
        """The expert's cross-attention keys/values over everything in ``seq`` (prefix, and the
        reasoning when there is one) and the think logit at <act> (sequence index ``act_pos``)."""
        think = None
        if self.cfg.reasoning and act_pos is not None:
            rows = torch.arange(seq.hidden.shape[0], device=seq.hidden.device)
            think = self.think_head(seq.hidden[rows, act_pos]).squeeze(-1)
        return Condition(self.expert.memory_kv(seq.hidden), seq.valid[:, None, None, :], think)

    # -- actions ----------------------------------------------------------------------------------
    def sample_actions(self, cond: Condition, noise: torch.Tensor, steps: int | None = None) -> torch.Tensor:
        """Euler integration of the flow from noise (t = 1) to actions (t = 0); returns actions in
        the dataset's units, (B, horizon, 7)."""
        steps = steps or self.cfg.flow_steps
        if cond.rows not in (1, noise.shape[0]):
            raise InvalidInput(f"{noise.shape[0]} noise rows for a condition of {cond.rows} rows")
        x, dt = noise, -1.0 / steps
        t = torch.ones(noise.shape[0], device=noise.device)
        for _ in range(steps):
            x = x + dt * self.expert(x, t, cond.kv, cond.mask).float()  # the sum stays fp32 under autocast
            t = t + dt
        return x * self.action_std + self.action_mean

    # -- training ---------------------------------------------------------------------------------
    def loss(self, batch: dict, gen: torch.Generator | None = None) -> tuple[torch.Tensor, dict]:
        """The training objective on one batch (keys: see `seal.train.vla.Batch`); ``gen`` draws the
        flow noise and times (seeded, saved with a checkpoint for an exact resume)."""
        cfg = self.cfg
        seq = self.encode_prefix(batch["agent"], batch["wrist"], batch["state"], batch["instr_ids"],
                                 batch["instr_valid"])
        metrics: dict = {}
        total = torch.zeros((), device=self.device)
        act_pos = None
        if cfg.reasoning:
            ids, valid = batch["reason_ids"], batch["reason_valid"]
            seq = self.extend(seq, ids, valid)
            hidden = seq.hidden[:, cfg.prefix_tokens:]
            # position j predicts token j+1; the last real token (<act>) predicts nothing
            logits = self.text_logits(hidden[:, :-1]).float()
            target = ids[:, 1:]
            weight = (valid[:, 1:].float() * batch["text_mask"].float()[:, None])
            ce = F.cross_entropy(logits.reshape(-1, logits.shape[-1]), target.reshape(-1), reduction="none")
            text = (ce * weight.reshape(-1)).sum() / weight.sum().clamp_min(1.0)
            act_pos = cfg.prefix_tokens + batch["act_index"]
            metrics["text"] = text.detach()
            total = total + cfg.text_weight * text
        cond = self.condition(seq, act_pos)
        if cond.think_logit is not None:
            think = F.binary_cross_entropy_with_logits(cond.think_logit.float(), batch["think"].float(),
                                                       reduction="none")
            tw = batch["think_mask"].float() if "think_mask" in batch else torch.ones_like(think)
            think = (think * tw).sum() / tw.sum().clamp_min(1.0)
            metrics["think"] = think.detach()
            total = total + cfg.think_weight * think
        # flow matching on the normalised chunk; padded steps and think samples carry no loss
        actions = (batch["actions"].float() - self.action_mean) / self.action_std
        b = actions.shape[0]
        noise = torch.randn(actions.shape, generator=gen, device="cpu").to(actions.device)
        u = torch.rand(b, generator=gen, device="cpu").to(actions.device)
        t = u.pow(1.0 / 1.5) * 0.999 + 0.001  # Beta(1.5, 1) by inverse CDF: F(x) = x^1.5
        x_t = t[:, None, None] * noise + (1 - t[:, None, None]) * actions
        v = self.expert(x_t, t, cond.kv, cond.mask).float()
        err = (v - (noise - actions)).pow(2).mean(-1)  # (B, horizon)
        w = batch["action_valid"].float() * batch["action_mask"].float()[:, None]
        flow = (err * w).sum() / w.sum().clamp_min(1.0)
        metrics["action"] = flow.detach()
        total = total + cfg.action_weight * flow
        metrics["loss"] = total.detach()
        return total, metrics


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
