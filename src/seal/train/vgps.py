"""V-GPS training: the value function (`seal.value.vgps`) fitted offline by IQL, in one file.

The baseline the paper compares against (pi0-V-GPS) samples K action chunks and executes the one
a Q-function rates highest. The Q-function is learned offline with Implicit Q-Learning (IQL):

    V(s, g)    <- expectile_tau of  min_i Q_target_i(s, a, g)          (never queries unseen actions)
    Q_i(s,a,g) <- r + gamma * (1 - done) * V(s', g)

Everything is sized for a CPU: a 56x56 agent view through a three-layer CNN, the 8-d state, the
executed chunk (5 x 7) and the goal text as hashed word/bigram buckets (the network and its
inputs: `seal.value`).

`train_value` writes, every ``save_every`` updates, the scorer's checkpoint (``value.safetensors``
+ ``value.json`` + ``manifest.json``, `seal.value.vgps.save_scorer`) and the training state
(``checkpoint.pt``: target networks, optimizer, generators; tensors and plain values only, read
with ``weights_only=True``), each atomically, and a metrics JSONL as it goes; running it again on
the same directory continues from them. `seal.value.vgps.VGPSScorer` loads the checkpoint for the
steering loop.
"""

from __future__ import annotations

import copy
import hashlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from seal.checkpoint import atomic_write
from seal.errors import InvalidInput
from seal.train.fields import check_integer, check_real
from seal.train.transitions import Transitions
from seal.value.vgps import ValueNets, goal_batch, save_scorer

try:
    import torch
    from torch.nn import functional as F
except ImportError as exc:  # torch is an extra: the steering loop itself never needs it
    raise ImportError("V-GPS training and scoring need PyTorch: pip install -e '.[train]' "
                      "(pins torch==2.13.0, a CPU build)") from exc

CHECKPOINT = "checkpoint.pt"
METRICS = "metrics.jsonl"


@dataclass(frozen=True)
class IQLConfig:
    """Hyperparameters; everything that changes the result is here and saved with the weights."""

    steps: int = 3000
    batch_size: int = 128
    lr: float = 3e-4
    gamma: float = 0.9           # per chunk of 5 steps (~0.98 per control step)
    expectile: float = 0.7       # IQL's tau: how optimistic V is about the data's best actions
    polyak: float = 0.005        # target-network update rate
    hidden: int = 256
    goal_dim: int = 64
    shift: int = 2               # random-shift augmentation, pixels (DrQ style)
    seed: int = 0
    save_every: int = 500
    log_every: int = 50

    def __post_init__(self) -> None:
        """Refuse a value that would fail (or silently train something else) after the data loads."""
        for name, low in (("steps", 0), ("batch_size", 1), ("hidden", 1), ("goal_dim", 1), ("shift", 0),
                          ("seed", 0), ("save_every", 1), ("log_every", 1)):
            check_integer(self, name, low)
        check_real(self, "lr", lambda v: v > 0, "a finite number > 0")
        check_real(self, "gamma", lambda v: 0 <= v < 1, "in [0, 1) (the discount per 5-step chunk)")
        check_real(self, "expectile", lambda v: 0 < v < 1, "in (0, 1) (IQL's tau; 0.5 is plain regression)")
        check_real(self, "polyak", lambda v: 0 < v <= 1, "in (0, 1] (the target network's update rate)")


def _random_shift(images: torch.Tensor, pad: int, gen: torch.Generator) -> torch.Tensor:
    """Pad by ``pad`` (edge) and crop back at a random offset per image."""
    if pad == 0:
        return images
    n, h, w, _ = images.shape
    padded = F.pad(images.permute(0, 3, 1, 2).float(), (pad,) * 4, mode="replicate").permute(0, 2, 3, 1)
    dx = torch.randint(0, 2 * pad + 1, (n,), generator=gen)
    dy = torch.randint(0, 2 * pad + 1, (n,), generator=gen)
    rows = (dy[:, None] + torch.arange(h)[None])[:, :, None].expand(n, h, w)
    cols = (dx[:, None] + torch.arange(w)[None])[:, None, :].expand(n, h, w)
    return padded[torch.arange(n)[:, None, None], rows, cols]


def iql_update(nets: ValueNets, target: ValueNets, opt: torch.optim.Optimizer, batch: dict,
               cfg: IQLConfig) -> dict:
    """One gradient step on the V (expectile) and Q (TD) losses; returns scalar metrics."""
    feat = nets.encoder(batch["image"], batch["state"], batch["goal"])
    with torch.no_grad():
        t_feat = target.encoder(batch["image"], batch["state"], batch["goal"])
        q_target = torch.min(*target.q(t_feat, batch["action"]))
        next_v = nets.v(nets.encoder(batch["next_image"], batch["next_state"], batch["goal"])).squeeze(-1)
        td_target = batch["reward"] + cfg.gamma * (1.0 - batch["done"]) * next_v
    v = nets.v(feat.detach()).squeeze(-1)
    diff = q_target - v
    weight = torch.where(diff > 0, cfg.expectile, 1.0 - cfg.expectile)
    v_loss = (weight * diff.pow(2)).mean()
    q1, q2 = nets.q(feat, batch["action"])
    q_loss = F.mse_loss(q1, td_target) + F.mse_loss(q2, td_target)
    opt.zero_grad()
    (q_loss + v_loss).backward()
    opt.step()
    with torch.no_grad():
        for p, tp in zip(nets.parameters(), target.parameters()):
            tp.lerp_(p, cfg.polyak)
    return {"q_loss": q_loss.item(), "v_loss": v_loss.item(), "q_mean": q1.mean().item(), "v_mean": v.mean().item()}


def _batch(data: Transitions, idx: np.ndarray, cfg: IQLConfig, gen: torch.Generator | None) -> dict:
    image = torch.from_numpy(data.image[idx])
    next_image = torch.from_numpy(data.next_image[idx])
    if gen is not None:
        image, next_image = _random_shift(image, cfg.shift, gen), _random_shift(next_image, cfg.shift, gen)
    return {"image": image, "next_image": next_image,
            "state": torch.from_numpy(data.state[idx]), "next_state": torch.from_numpy(data.next_state[idx]),
            "action": torch.from_numpy(data.action[idx]), "goal": goal_batch([data.goal[i] for i in idx]),
            "reward": torch.from_numpy(data.reward[idx]), "done": torch.from_numpy(data.done[idx])}


def data_fingerprint(data: Transitions) -> str:
    """Identifies the training data, so a resumed run refuses a different dataset."""
    h = hashlib.sha1()
    for arr in (data.state, data.action, data.reward):
        h.update(np.ascontiguousarray(arr).tobytes())
    h.update("\n".join(data.goal).encode())
    return h.hexdigest()[:12]


def train_value(data: Transitions, out: Path, cfg: IQLConfig, *, progress=None, threads: int | None = 1,
                image_size: int = 224) -> dict:
    """Train (or continue training) a value function on ``data``; returns the last metrics.

    ``image_size``: the side of the camera frames the transitions were made from (224: openpi's
    view; 64: a 64-px policy's). It is saved with the weights, so the scorer asks the loop for the
    same view.

    ``threads``: torch's intra-op threads. One by default: these small batches gain little from
    more, and on a shared 2-core machine oversubscribed threads made training ~10x slower.
    """
    if threads:
        torch.set_num_threads(threads)
    if len(data) < cfg.batch_size:
        raise InvalidInput(f"{len(data)} transitions, fewer than one batch ({cfg.batch_size}); "
                           "record more episodes or lower --batch-size")
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(cfg.seed)
    fingerprint = data_fingerprint(data)
    nets = ValueNets(cfg.hidden, cfg.goal_dim)
    target = copy.deepcopy(nets).requires_grad_(False)
    opt = torch.optim.Adam(nets.parameters(), lr=cfg.lr)
    rng = np.random.default_rng(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    step = 0
    ckpt_path = out / CHECKPOINT
    if ckpt_path.exists():
        ckpt = torch.load(ckpt_path, weights_only=True)
        saved = {k: v for k, v in ckpt["config"].items() if k not in ("steps", "save_every", "log_every")}
        mine = {k: v for k, v in asdict(cfg).items() if k not in ("steps", "save_every", "log_every")}
        if saved != mine or ckpt["data"] != fingerprint:
            raise InvalidInput(f"{ckpt_path} was trained with other settings or data "
                               f"(saved {saved}, data {ckpt['data']}; now {mine}, data {fingerprint}); "
                               "use another --out directory")
        nets.load_state_dict(ckpt["nets"])
        target.load_state_dict(ckpt["target"])
        opt.load_state_dict(ckpt["opt"])
        rng.bit_generator.state = ckpt["rng"]
        gen.set_state(ckpt["gen"])
        step = ckpt["step"]
    last: dict = {}
    t0, t_step = time.perf_counter(), step
    with open(out / METRICS, "a") as log:
        while step < cfg.steps:
            idx = rng.integers(0, len(data), cfg.batch_size)
            last = iql_update(nets, target, opt, _batch(data, idx, cfg, gen), cfg)
            step += 1
            if step % cfg.log_every == 0 or step == cfg.steps:
                last |= {"step": step, "steps_per_s": round((step - t_step) / (time.perf_counter() - t0), 2)}
                log.write(json.dumps(last) + "\n")
                log.flush()
            if step % cfg.save_every == 0 or step == cfg.steps:
                meta = {"config": asdict(cfg), "data": fingerprint, "step": step, "image_size": image_size}
                save_scorer(out, nets, meta)
                _save(ckpt_path, meta | {"nets": nets.state_dict(), "target": target.state_dict(),
                                         "opt": opt.state_dict(), "rng": rng.bit_generator.state,
                                         "gen": gen.get_state()})
            if progress:
                progress(step, last)
    return last | {"step": step}


def _save(path: Path, obj: dict) -> None:
    atomic_write(path, lambda p: torch.save(obj, p))  # a crash mid-write leaves the previous one intact


@torch.no_grad()
def evaluate_value(nets: ValueNets, data: Transitions, cfg: IQLConfig, batch: int = 256) -> dict:
    """How well Q on the recorded chunks tracks the true discounted return (held-out data).

    ``return_spearman``: rank correlation of Q(s, a, g) with gamma^(chunks to goal - 1) (0 when the
    goal is never reached). ``goal_accuracy``: over chunks one or two chunks before their goal is
    reached, how often Q rates the chunk higher for that goal than for another goal text seen in
    the data — whether the goal text matters at all, which the value method relies on.
    """
    nets.eval()
    qs, swapped = [], []
    goals = sorted(set(data.goal))
    rng = np.random.default_rng(0)
    for lo in range(0, len(data), batch):
        idx = np.arange(lo, min(lo + batch, len(data)))
        b = _batch(data, idx, cfg, None)
        qs.append(torch.min(*nets.q(nets.encoder(b["image"], b["state"], b["goal"]), b["action"])).numpy())
        other = [goals[(goals.index(data.goal[i]) + 1 + rng.integers(len(goals) - 1)) % len(goals)]
                 if len(goals) > 1 else data.goal[i] for i in idx]
        feat = nets.encoder(b["image"], b["state"], goal_batch(other))
        swapped.append(torch.min(*nets.q(feat, b["action"])).numpy())
    nets.train()
    q, q_other = np.concatenate(qs), np.concatenate(swapped)
    truth = np.where(data.to_goal > 0, cfg.gamma ** np.maximum(data.to_goal - 1, 0), 0.0)
    from scipy.stats import spearmanr

    rho = spearmanr(q, truth).statistic if np.ptp(truth) > 0 else float("nan")
    near = (data.to_goal >= 1) & (data.to_goal <= 2)
    acc = float(np.mean(q[near] > q_other[near])) if near.any() else float("nan")
    return {"return_spearman": round(float(rho), 3), "goal_accuracy": round(acc, 3),
            "transitions": len(data)}
