"""The V-GPS value function at run time: the Q-network over (agent view, state, goal text, chunk),
its checkpoint files, and `VGPSScorer`, the steering loop's ``value`` scorer (`seal.steer.scoring`).

The network is one small CNN encoder with the 8-d state and the goal text as hashed word and
bigram buckets averaged by an EmbeddingBag (no pretrained language model can be downloaded here;
words never seen in training land in untrained buckets, which is exactly the OOD weakness the
paper points out), two Q heads and a V head. `seal.train.vgps` trains it with IQL and writes the
checkpoint through `save_scorer`: ``value.safetensors`` + ``value.json`` + ``manifest.json``
(`seal.checkpoint`), the manifest last. `VGPSScorer.load` checks it against its manifest.
"""

from __future__ import annotations

import json
import re
import zlib
from pathlib import Path

import numpy as np

from seal.checkpoint import atomic_write, verify, write_manifest
from seal.errors import InvalidInput
from seal.policies.base import ACTION_HORIZON
from seal.value import VALUE_CONFIG, VALUE_FILES, VALUE_KIND, VALUE_WEIGHTS, value_directory
from seal.value.inputs import IMAGE_SIDE, chunk_of, downsample

try:
    import torch
    from torch import nn
except ImportError as exc:  # torch is an extra: the steering loop itself never needs it
    raise ImportError("V-GPS training and scoring need PyTorch: pip install -e '.[train]' "
                      "(pins torch==2.13.0, a CPU build)") from exc

GOAL_BUCKETS = 4096


def goal_tokens(text: str) -> list[int]:
    """Hashed lower-case words and word bigrams -> bucket ids (stable across processes: crc32)."""
    words = re.findall(r"[a-z0-9]+", text.lower())
    grams = words + [f"{a} {b}" for a, b in zip(words, words[1:])]
    return [zlib.crc32(g.encode()) % GOAL_BUCKETS for g in grams] or [0]


def goal_batch(texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
    """EmbeddingBag inputs (flat ids, offsets) for a batch of goal texts."""
    ids, offsets = [], []
    for t in texts:
        offsets.append(len(ids))
        ids.extend(goal_tokens(t))
    return torch.tensor(ids, dtype=torch.long), torch.tensor(offsets, dtype=torch.long)


class Encoder(nn.Module):
    """(image, state, goal) -> feature vector shared by the Q and V heads."""

    def __init__(self, hidden: int, goal_dim: int):
        super().__init__()
        self.conv = nn.Sequential(
            nn.Conv2d(3, 32, 5, stride=2), nn.ReLU(),   # 56 -> 26
            nn.Conv2d(32, 64, 3, stride=2), nn.ReLU(),  # 26 -> 12
            nn.Conv2d(64, 64, 3, stride=2), nn.ReLU(),  # 12 -> 5
            nn.Flatten(), nn.Linear(64 * 5 * 5, hidden), nn.LayerNorm(hidden), nn.Tanh())
        self.goal = nn.EmbeddingBag(GOAL_BUCKETS, goal_dim, mode="mean")
        self.out_dim = hidden + 8 + goal_dim

    def forward(self, image: torch.Tensor, state: torch.Tensor, goal: tuple[torch.Tensor, torch.Tensor]):
        x = image.permute(0, 3, 1, 2).float() / 255.0
        return torch.cat([self.conv(x), state, self.goal(*goal)], dim=-1)


def _mlp(inp: int, hidden: int) -> nn.Module:
    return nn.Sequential(nn.Linear(inp, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                         nn.Linear(hidden, 1))


class ValueNets(nn.Module):
    """One encoder, two Q heads (clipped double Q) and a V head; ``hidden`` and ``goal_dim`` are the
    training config's (`seal.train.vgps.IQLConfig`, saved with the weights)."""

    def __init__(self, hidden: int = 256, goal_dim: int = 64):
        super().__init__()
        self.encoder = Encoder(hidden, goal_dim)
        act_dim = 7 * ACTION_HORIZON
        self.q1 = _mlp(self.encoder.out_dim + act_dim, hidden)
        self.q2 = _mlp(self.encoder.out_dim + act_dim, hidden)
        self.v = _mlp(self.encoder.out_dim, hidden)

    def q(self, feat: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = torch.cat([feat, action], dim=-1)
        return self.q1(x).squeeze(-1), self.q2(x).squeeze(-1)


def save_scorer(out: Path, nets: ValueNets, meta: dict) -> None:
    """The scorer's checkpoint in ``out``: weights, their config (``meta``), the manifest last."""
    from safetensors.torch import save_file

    (out / "manifest.json").unlink(missing_ok=True)  # no manifest = no checkpoint, until this one is complete
    state = {k: v.detach().contiguous().cpu() for k, v in nets.state_dict().items()}
    atomic_write(out / VALUE_WEIGHTS, lambda p: save_file(state, str(p), metadata={"format": VALUE_KIND}))
    atomic_write(out / VALUE_CONFIG, lambda p: p.write_text(json.dumps(meta, indent=1)))
    write_manifest(out, kind=VALUE_KIND, files=list(VALUE_FILES), extra={"step": meta["step"], "data": meta["data"]})


def load_scorer_nets(path: str | Path) -> tuple[ValueNets, dict]:
    """(networks in eval mode, their config) from a checkpoint directory, checked against its manifest."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    path = value_directory(path)
    verify(path, kind=VALUE_KIND, required=VALUE_FILES)
    try:
        meta = json.loads((path / VALUE_CONFIG).read_text())
        nets = ValueNets(meta["config"]["hidden"], meta["config"]["goal_dim"])
    except (ValueError, TypeError, KeyError) as exc:
        raise InvalidInput(f"{path / VALUE_CONFIG} describes no V-GPS model: {exc}") from None
    try:
        nets.load_state_dict(load_file(str(path / VALUE_WEIGHTS)))
    except (SafetensorError, RuntimeError) as exc:
        raise InvalidInput(f"{path / VALUE_WEIGHTS} does not fit {VALUE_CONFIG}: {exc}") from None
    return nets.eval(), meta


class VGPSScorer:
    """`ChunkScorer` over a trained checkpoint: Q(obs, chunk, goal), the min of the two heads."""

    needs_images = True

    def __init__(self, nets: ValueNets, source: str = "", image_size: int = 224):
        self.nets = nets.eval()
        self.source = source
        self.image_size = image_size  # the agent view it was trained on (checkpoints before this field: 224)

    @classmethod
    def load(cls, path: str | Path) -> VGPSScorer:
        nets, meta = load_scorer_nets(path)
        return cls(nets, source=str(value_directory(path)), image_size=int(meta.get("image_size", 224)))

    @torch.no_grad()
    def score(self, obs, chunks: np.ndarray, goal: str) -> np.ndarray:
        if obs.agent is None:
            raise InvalidInput("the V-GPS scorer needs the agent-view image; observe with images=True")
        k = len(chunks)
        image = torch.from_numpy(downsample(obs.agent))[None].expand(k, IMAGE_SIDE, IMAGE_SIDE, 3)
        state = torch.as_tensor(np.asarray(obs.state, dtype=np.float32))[None].expand(k, 8)
        action = torch.from_numpy(np.stack([chunk_of(c) for c in chunks]))
        feat = self.nets.encoder(image, state, goal_batch([goal] * k))
        return torch.min(*self.nets.q(feat, action)).numpy()
