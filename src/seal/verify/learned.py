"""A learned verifier that sees only what a VLM verifier sees: three views and the sub-plan text.

The model (`VerifierNet`, trained from scratch by `seal train verifier`, `seal.train.verifier`):

- images: the front view when the sub-plan began and at the candidate's end, stacked as one
  6-channel picture (so a change between them is visible to the first layer), and the wrist view
  at the end, each area-downsampled inside the model from 224 px to ``image_size`` (96 by
  default) and run through a small CNN of its own (4 stride-2 convolutions);
- text: the sub-plan and, as context, the sub-plan before it in the plan (what "it" in "place it
  in the basket" refers to), as word ids of a vocabulary built from the training texts
  (`WordVocab`; an unknown word maps to ``<unk>``), averaged word embeddings per text;
- the text modulates the last two convolution blocks of both CNNs (FiLM: a per-channel scale and
  shift), so the same pixels can mean success for one sub-plan and failure for another;
- output: one logit; P(success) = sigmoid(logit); success when P >= ``threshold`` (config).

A checkpoint is a directory: ``model.safetensors`` (weights), ``config.json`` (architecture,
vocabulary, threshold, training summary) and ``manifest.json`` (`seal.checkpoint`: both files'
sha256 and size, written last). Loading checks the files against the manifest before reading
them, then the config and every tensor's shape, and raises `InvalidInput` naming what is wrong.

`LearnedVerifier` implements the `Verifier` protocol; ``verify_batch`` judges many requests in
one forward pass, and the async ``verify`` batches the requests that arrive together on its
event loop (the K candidates of a round that end at the same time).
"""

from __future__ import annotations

import asyncio
import json
import re
import time
from pathlib import Path

import numpy as np

from seal.checkpoint import CheckpointFormat, atomic_write, write_manifest
from seal.errors import InvalidInput
from seal.verify.base import Verdict, VerifyRequest

DEFAULT_CHECKPOINT = Path(__file__).resolve().parent / "checkpoints" / "learned"
# Earlier shipped checkpoints, kept so the tables made with them stay reproducible: `learned:NAME`.
# expert: the first one (2026-12-02), trained on the scripted expert's rounds and demonstrations;
# vla_rounds: it fine-tuned on the first reasoning VLA's own rounds (shipped 2026-12-04 morning);
# dagger_rounds: that one with DAgger rounds 2-3 and task-level cases added (shipped 2026-12-04 to 12-05);
# pad_labels: it fine-tuned, failures weighted, on the round-2 VLA's SEAL rounds, picks labelled by the pad check
# (shipped 2026-12-05); later ones are set aside by `seal.verify.ship` with their label in their manifest
# (held_labels: that recipe on the same rounds labelled by Held, shipped 2026-12-05 until round 4's VLA shipped).
# Every directory beside the shipped one that holds a manifest is one (read once: the package's files).
SHIPPED = {p.name: p for p in sorted(DEFAULT_CHECKPOINT.parent.glob("*/"))
           if p.name != DEFAULT_CHECKPOINT.name and not p.name.startswith(".") and (p / "manifest.json").is_file()}
KIND = "seal-learned-verifier"
WEIGHTS = "model.safetensors"
CONFIG = "config.json"
FILES = (WEIGHTS, CONFIG)
# sha1 of the weights and config, as results stores have named a learned verifier from the start
CHECKPOINT = CheckpointFormat(KIND, required=FILES, named_by=FILES, algorithm="sha1")
ARCH_KEYS = ("image_size", "widths", "embed_dim", "max_words", "vocab")
PAD, UNK = "<pad>", "<unk>"


# ---- text ------------------------------------------------------------------------------------------
def words(text: str) -> list[str]:
    return re.findall(r"[a-z]+", text.lower())


class WordVocab:
    """Word-level vocabulary: id 0 is padding, id 1 any word not seen in training."""

    def __init__(self, tokens: list[str]):
        if tokens[:2] != [PAD, UNK]:
            raise InvalidInput(f"a vocabulary must start with {PAD!r}, {UNK!r}; got {tokens[:2]}")
        self.tokens = list(tokens)
        self.index = {t: i for i, t in enumerate(self.tokens)}

    @classmethod
    def build(cls, texts, min_count: int = 1) -> "WordVocab":
        counts: dict[str, int] = {}
        for text in texts:
            for w in words(text):
                counts[w] = counts.get(w, 0) + 1
        return cls([PAD, UNK] + sorted(w for w, n in counts.items() if n >= min_count))

    def __len__(self) -> int:
        return len(self.tokens)

    def encode(self, texts: list[str], max_words: int) -> np.ndarray:
        out = np.zeros((len(texts), max_words), dtype=np.int64)
        for i, text in enumerate(texts):
            ids = [self.index.get(w, 1) for w in words(text)][:max_words]
            out[i, : len(ids)] = ids
        return out


def context_of(subplan: str, plans, index: int | None) -> str:
    """The sub-plan before this one in the plan ('' for the first)."""
    plans = list(plans or ())
    if index is None:
        index = plans.index(subplan) if subplan in plans else -1
    return plans[index - 1] if index is not None and index > 0 else ""


# ---- the network -----------------------------------------------------------------------------------
def _torch():
    try:
        import torch
    except ImportError as exc:  # pragma: no cover - torch is a dependency of the training extras
        raise InvalidInput("the learned verifier needs torch: pip install torch") from exc
    return torch


def build_net(config: dict):
    """The `VerifierNet` a config describes (weights random until loaded)."""
    torch = _torch()
    nn, F = torch.nn, torch.nn.functional

    class FiLMCNN(nn.Module):
        def __init__(self, in_ch: int, widths, text_dim: int, film_from: int = 2):
            super().__init__()
            chans = [in_ch, *widths]
            self.convs = nn.ModuleList(nn.Conv2d(a, b, 3, stride=2, padding=1) for a, b in zip(chans, chans[1:]))
            self.norms = nn.ModuleList(nn.GroupNorm(8, b) for b in widths)
            self.film_from = film_from
            self.films = nn.ModuleList(nn.Linear(text_dim, 2 * b) for b in widths[film_from:])

        def forward(self, x, t):
            for i, (conv, norm) in enumerate(zip(self.convs, self.norms)):
                x = norm(conv(x))
                if i >= self.film_from:
                    gamma, beta = self.films[i - self.film_from](t).chunk(2, dim=1)
                    x = x * (1 + gamma[:, :, None, None]) + beta[:, :, None, None]
                x = F.relu(x)
            return torch.cat([x.mean(dim=(2, 3)), x.amax(dim=(2, 3))], dim=1)

    class VerifierNet(nn.Module):
        def __init__(self, cfg: dict):
            super().__init__()
            self.image_size = int(cfg["image_size"])
            widths = [int(w) for w in cfg["widths"]]
            d = int(cfg["embed_dim"])
            self.embed = nn.Embedding(len(cfg["vocab"]), d, padding_idx=0)
            self.text = nn.Sequential(nn.Linear(2 * d, 2 * d), nn.ReLU())
            self.agent = FiLMCNN(6, widths, 2 * d)
            self.wrist = FiLMCNN(3, widths, 2 * d)
            self.head = nn.Sequential(nn.Linear(4 * widths[-1] + 2 * d, 128), nn.ReLU(), nn.Linear(128, 1))

        def _bag(self, ids):
            mask = (ids > 0).float()
            return (self.embed(ids) * mask[..., None]).sum(1) / mask.sum(1, keepdim=True).clamp(min=1.0)

        def forward(self, first, final, wrist, subplan_ids, context_ids):
            """Images (B, 3, s, s) float in [0, 1] at ``image_size``; word ids (B, max_words)."""
            t = self.text(torch.cat([self._bag(subplan_ids), self._bag(context_ids)], dim=1))
            a = self.agent(torch.cat([first, final], dim=1) - 0.5, t)
            w = self.wrist(wrist - 0.5, t)
            return self.head(torch.cat([a, w, t], dim=1)).squeeze(1)

    return VerifierNet(config)


def prepare_images(images: np.ndarray, size: int):
    """(B, H, W, 3) uint8 -> (B, 3, size, size) float in [0, 1], area-downsampled and rounded to
    whole 8-bit levels (the model's own preprocessing; training data goes through the same function
    and is cached as 8-bit pixels, so the rounding makes a verdict see exactly what training saw)."""
    torch = _torch()
    # contiguous before the resize: "area" on the permuted (channels-last) strides is ~2.5x slower
    # on CPU, and the result is the same to the bit
    x = torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).contiguous().float().div_(255.0)
    if x.shape[-1] != size or x.shape[-2] != size:
        x = torch.nn.functional.interpolate(x, size=(size, size), mode="area").mul_(255.0).round_().div_(255.0)
    return x


def default_config(vocab: WordVocab, image_size: int = 96) -> dict:
    return {"model": "seal-learned-verifier", "version": 1, "image_size": image_size, "widths": [32, 64, 96, 128],
            "embed_dim": 64, "max_words": 16, "threshold": 0.5, "vocab": vocab.tokens}


# ---- checkpoints -------------------------------------------------------------------------------------
def save_checkpoint(path: Path, net, config: dict, manifest: dict | None = None) -> None:
    """``model.safetensors`` + ``config.json`` under ``path``, each written aside and renamed, then
    the manifest that vouches for both (with ``manifest``'s entries: data, figures, command)."""
    from safetensors.torch import save_file

    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    (path / "manifest.json").unlink(missing_ok=True)  # no manifest = no checkpoint, until this one is complete
    state = {k: v.detach().contiguous().cpu() for k, v in net.state_dict().items()}
    atomic_write(path / WEIGHTS, lambda p: save_file(state, str(p), metadata={"format": KIND}))
    atomic_write(path / CONFIG, lambda p: p.write_text(json.dumps(config, indent=1)))
    write_manifest(path, kind=KIND, files=list(FILES), extra={"model": KIND, **(manifest or {})})


def load_checkpoint(path: str | Path | None):
    """(net in eval mode, config, vocab) from a checkpoint directory (or its model.safetensors)."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    path = checkpoint_dir(path)
    CHECKPOINT.verify(path)  # every byte checked before any is parsed
    try:
        config = json.loads((path / CONFIG).read_text())
    except (OSError, ValueError) as exc:
        raise InvalidInput(f"{path / CONFIG} is not valid JSON: {exc}") from None
    if not isinstance(config, dict):
        raise InvalidInput(f"{path / CONFIG} must hold a JSON object")
    missing = [k for k in ARCH_KEYS if k not in config]
    if missing:
        raise InvalidInput(f"{path / CONFIG} lacks {', '.join(missing)}")
    try:
        vocab = WordVocab(list(config["vocab"]))
        net = build_net(config)
    except (TypeError, ValueError, KeyError) as exc:
        raise InvalidInput(f"{path / CONFIG} describes no valid model: {exc}") from None
    try:
        state = load_file(str(path / WEIGHTS))
    except (SafetensorError, OSError, ValueError) as exc:
        raise InvalidInput(f"{path / WEIGHTS} is not a readable safetensors file (truncated?): {exc}") from None
    expected = net.state_dict()
    extra, absent = sorted(set(state) - set(expected)), sorted(set(expected) - set(state))
    if extra or absent:
        raise InvalidInput(f"{path / WEIGHTS} does not match {CONFIG}: missing tensors {absent[:5]}, "
                           f"unexpected tensors {extra[:5]}")
    for name, tensor in expected.items():
        if tuple(state[name].shape) != tuple(tensor.shape):
            raise InvalidInput(f"{path / WEIGHTS}: tensor {name!r} has shape {tuple(state[name].shape)}, "
                               f"{CONFIG} needs {tuple(tensor.shape)}")
    net.load_state_dict(state)
    net.eval()
    return net, config, vocab


def checkpoint_dir(path: str | Path | None) -> Path:
    """The checkpoint directory ``path`` names: ``learned`` or None (the shipped one), a name in ``SHIPPED``
    (an earlier shipped checkpoint), a directory, or a file in one."""
    names = {"learned": DEFAULT_CHECKPOINT, **SHIPPED}
    path = names.get(str(path), Path(path)) if path else DEFAULT_CHECKPOINT
    path = path.parent if path.is_file() else path
    if not path.is_dir():
        raise InvalidInput(f"no learned-verifier checkpoint at {path}: train one with `seal train verifier --data DIR "
                           f"--out RUN` and pass learned:RUN")
    return path


# ---- the verifier ------------------------------------------------------------------------------------
class LearnedVerifier:
    """P(success) from the three views and the sub-plan; batched over the requests of a round."""

    needs_images = True

    def __init__(self, path: str | Path | None = None, *, threshold: float | None = None, threads: int | None = 1):
        """``threads``: torch's intra-op threads (process-wide). One by default: on this 2-core
        machine shared with simulator workers, two threads made a K=10 batch ~10x slower."""
        torch = _torch()
        self.path = checkpoint_dir(path)
        self.net, self.config, self.vocab = load_checkpoint(self.path)
        self.threshold = float(self.config.get("threshold", 0.5) if threshold is None else threshold)
        if not 0.0 <= self.threshold <= 1.0:
            raise InvalidInput(f"threshold must be in [0, 1], got {self.threshold}")
        if threads is not None:
            torch.set_num_threads(int(threads))
        self.name = f"learned:{self.path}"
        self.batches = 0  # forward passes run (tests read it)
        self._pending: dict = {}  # event loop -> [(request, future)]

    def atoms_needed(self, request: VerifyRequest, objects: list[str]) -> list[str]:
        return []  # pixels and text only

    def probabilities(self, requests: list[VerifyRequest]) -> np.ndarray:
        torch = _torch()
        size, n = self.net.image_size, int(self.config["max_words"])
        views = []
        for name in ("first_agent", "final_agent", "final_wrist"):
            arrays = [getattr(r, name) for r in requests]
            for a in arrays:
                if a is None or np.asarray(a).ndim != 3 or np.asarray(a).shape[2] != 3:
                    raise InvalidInput(f"the learned verifier needs request.{name} (an HxWx3 uint8 image)")
            views.append(prepare_images(np.stack(arrays), size))
        sub = torch.from_numpy(self.vocab.encode([r.subplan for r in requests], n))
        ctx = torch.from_numpy(self.vocab.encode([context_of(r.subplan, r.plans, r.index) for r in requests], n))
        with torch.inference_mode():
            logits = self.net(*views, sub, ctx)
        self.batches += 1
        return torch.sigmoid(logits).numpy().astype(np.float64)

    def verify_batch(self, requests: list[VerifyRequest]) -> list[Verdict]:
        if not requests:
            return []
        start = time.perf_counter()
        probs = self.probabilities(requests)
        each = (time.perf_counter() - start) / len(requests)
        return [self._verdict(p, each, len(requests)) for p in probs]

    def _verdict(self, p: float, latency_s: float, batch: int) -> Verdict:
        if not np.isfinite(p):  # broken weights or inputs: no answer, counted as a verifier error, never a "fail"
            why = f"the learned verifier's P(success) is not finite ({p}); its checkpoint or inputs are broken"
            return Verdict(None, f"unknown: {why}", latency_s=latency_s, raw=str(p),
                           extra={"batch": batch, "error": why})
        return Verdict(bool(p >= self.threshold), f"P(success) = {p:.3f} (threshold {self.threshold:g})",
                       latency_s=latency_s, raw=f"{p:.6f}", score=float(p), extra={"batch": batch})

    async def verify(self, request: VerifyRequest) -> Verdict:
        loop = asyncio.get_running_loop()
        future = loop.create_future()
        queue = self._pending.setdefault(loop, [])
        queue.append((request, future))
        if len(queue) == 1:  # the first of a batch: judge once the requests already queued are in
            loop.call_soon(self._flush, loop)
        return await future

    def _flush(self, loop) -> None:
        batch = [(r, f) for r, f in self._pending.pop(loop, []) if not f.done()]
        if not batch:
            return
        try:
            verdicts = self.verify_batch([r for r, _ in batch])
        except Exception as exc:  # every waiting request gets the error
            for _, f in batch:
                if not f.done():
                    f.set_exception(exc)
            return
        for (_, f), v in zip(batch, verdicts):
            if not f.done():
                f.set_result(v)
