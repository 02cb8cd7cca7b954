"""`seal train verifier`: the learned verifier (`seal.verify.learned`) from verification cases.

Data: one or more `seal verify collect` directories (`seal.verify.dataset`), e.g. LIBERO-10 cases
and LIBERO-90 cases collected apart (a collection holds one suite). Images are decoded once and
downsampled to the model's input size with the model's own function (`prepare_images`), then
kept in memory as uint8 and cached in ``RUN/cache-<size>.npz``.

Held-out data, two ways:

- by whole task: ``holdout_tasks`` (e.g. ``libero_10/1,libero_90/12``): none of their cases is
  trained on; pick tasks whose kinds of action (pick, place, open...) other tasks also have;
- by init state: of every other task, a fixed fraction of its init states (chosen by a hash of
  task, init source and index) is held out with all its cases.

Checkpoints: ``RUN/model.safetensors`` + ``RUN/config.json`` (the verifier loads RUN), and
``RUN/train_state.pt`` (optimizer and step), written every ``save_every_s`` seconds and at the end,
each aside then renamed. Batches and augmentation are drawn from generators seeded by (seed,
step), so continuing from a checkpoint gives the same weights as never stopping. Logs:
``metrics.jsonl`` (loss every ``log_every`` steps, held-out figures at every evaluation),
``metrics.json`` (the final figures) and ``loss_curve.png``.
"""

from __future__ import annotations

import collections
import copy
import hashlib
import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from seal.errors import InvalidInput
from seal.train.fields import check_integer, check_real
from seal.verify import dataset as ds
from seal.verify.dataset import binary_metrics, init_key_of
from seal.verify.learned import (ARCH_KEYS, CHECKPOINT, WordVocab, build_net, checkpoint_dir, context_of, default_config,
                                 load_checkpoint, prepare_images, save_checkpoint, words)

try:
    import torch
    from torch.nn import functional as F
except ImportError as exc:  # torch is an extra: the steering loop itself never needs it
    raise ImportError("training the learned verifier needs PyTorch: pip install -e '.[train]'") from exc

STATE = "train_state.pt"
METRICS = "metrics.jsonl"


@dataclass(frozen=True)
class VerifierTrainConfig:
    steps: int = 2000
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 1e-4
    image_size: int = 96
    holdout_tasks: tuple[str, ...] = ()
    holdout_inits: float = 0.2  # fraction of each remaining task's init states held out
    seed: int = 0  # the held-out split (and, without train_seed, everything else)
    # the initial weights, batches and augmentation; None: ``seed``. Another train_seed on the same
    # split measures how much two runs of one recipe differ.
    train_seed: int | None = None
    shift: int = 4  # augmentation: random translation in pixels (at image_size)
    # augmentation: per-case brightness and contrast factors in [1 - jitter, 1 + jitter], one pair for
    # both front views (their difference is the evidence) and one for the wrist view
    jitter: float = 0.0
    # "constant", or "cosine": lr * (1 + cos(pi * step / steps)) / 2, which ends training at a small step
    # size (the held-out figures of a constant-lr run swing by several points between evaluations)
    lr_schedule: str = "constant"
    # > 0: the checkpoint holds an exponential moving average of the weights with this decay (e.g.
    # 0.999, ~1000 steps), which is also what is evaluated; the raw weights go on training. A
    # constant-lr run's held-out figures swing by several points between evaluations, so the last
    # raw weights are a draw; the average is steadier. 0: off (the raw weights are the checkpoint).
    ema: float = 0.0
    # Cost-sensitive loss. With the reasoning VLA a false pass costs SEAL the episode and a refusal costs a
    # round (docs/verifier.md, the noise sweeps), so a failed case may weigh more than a successful one.
    negative_weight: float = 1.0
    # With --init-from: the failed training cases the initial checkpoint passes (its confident false
    # successes, the hard negatives issue 32 asks for) weigh this much more again. 1: off.
    hard_negative_weight: float = 1.0
    log_every: int = 20
    eval_every: int = 200
    save_every_s: float = 300.0

    def __post_init__(self) -> None:
        """Refuse settings that would fail minutes later (after the images are decoded) or train
        something other than asked; every message names the field, the value and what is valid."""
        check_integer(self, "steps", 0, what=" (0: the initial weights)")
        check_integer(self, "batch_size", 1)
        check_real(self, "lr", lambda v: v > 0, "a finite number > 0")
        check_real(self, "weight_decay", lambda v: v >= 0, "a finite number >= 0")
        check_integer(self, "image_size", 8, ds.IMAGE_SIZE, f" (the cases are {ds.IMAGE_SIZE} px)")
        if isinstance(self.holdout_tasks, str) or not all(isinstance(t, str) for t in self.holdout_tasks):
            raise InvalidInput(f"holdout_tasks must be a tuple of task keys like 'libero_10/1', got "
                               f"{self.holdout_tasks!r}")
        check_real(self, "holdout_inits", lambda v: 0 <= v < 1,
                   "in [0, 1) (a fraction of each task's init states)")
        check_integer(self, "seed", 0)
        if self.train_seed is not None:
            check_integer(self, "train_seed", 0, what=" or None")
        check_integer(self, "shift", 0, self.image_size - 1, " (pixels at image_size)")
        check_real(self, "jitter", lambda v: 0 <= v < 1,
                   "in [0, 1) (brightness/contrast factors in [1 - jitter, 1 + jitter]; 0: off)")
        if self.lr_schedule not in ("constant", "cosine"):
            raise InvalidInput(f"lr schedule {self.lr_schedule!r} is not one of: constant, cosine")
        if isinstance(self.ema, bool) or not isinstance(self.ema, (int, float, np.number)) or not 0 <= self.ema < 1:
            raise InvalidInput(f"ema decay must be in [0, 1) (0: off; e.g. 0.999), got {self.ema!r}")
        check_real(self, "negative_weight", lambda v: v > 0, "a finite number > 0 (1: every case alike)")
        check_real(self, "hard_negative_weight", lambda v: v >= 1, "a finite number >= 1 (1: off)")
        check_integer(self, "log_every", 1)
        check_integer(self, "eval_every", 1)
        check_real(self, "save_every_s", lambda v: v >= 0, "a number of seconds >= 0")

    def identity(self) -> dict:
        """What a resumed run must share with the run it continues."""
        d = asdict(self)
        # a constant-lr run may be continued to more steps; a cosine run's schedule is its length
        for k in ("log_every", "eval_every", "save_every_s") + (("steps",) if self.lr_schedule == "constant" else ()):
            d.pop(k)
        if self.lr_schedule == "constant":  # runs from before the schedule existed stay resumable
            d.pop("lr_schedule")
        if self.train_seed is None:  # likewise runs from before train_seed existed
            d.pop("train_seed")
        if not self.ema:  # and runs from before the average existed
            d.pop("ema")
        for k in ("negative_weight", "hard_negative_weight"):  # and before the weights existed
            if d[k] == 1.0:
                d.pop(k)
        d["holdout_tasks"] = list(d["holdout_tasks"])
        return d

    @property
    def draw_seed(self) -> int:
        """The seed of the weights, batches and augmentation."""
        return self.seed if self.train_seed is None else self.train_seed

    def lr_at(self, step: int) -> float:
        if self.lr_schedule == "constant":
            return self.lr
        if self.lr_schedule == "cosine":
            return self.lr * 0.5 * (1.0 + math.cos(math.pi * min(step, self.steps) / self.steps))
        raise InvalidInput(f"lr schedule {self.lr_schedule!r} is not one of: constant, cosine")


# ---- data ----------------------------------------------------------------------------------------------
@dataclass
class CaseArrays:
    first: np.ndarray  # (n, 3, s, s) uint8
    final: np.ndarray
    wrist: np.ndarray
    subplan: list[str]
    context: list[str]
    label: np.ndarray  # (n,) float32
    task: list[str]
    kind: list[str]
    init_key: list[str]  # task:source:index
    source: list[str]  # init_source: cases from demonstrations ("demo") are training data only
    policy: list[str]  # the policy whose rounds made the case (scripted, vla, ...)

    def __len__(self) -> int:
        return len(self.label)


def _downsample(pngs: list[bytes], size: int) -> np.ndarray:
    out = np.empty((len(pngs), 3, size, size), dtype=np.uint8)
    for start in range(0, len(pngs), 256):
        chunk = np.stack([ds.decode_png(p) for p in pngs[start:start + 256]])
        out[start:start + len(chunk)] = (prepare_images(chunk, size) * 255.0).round().clamp(0, 255).byte().numpy()
    return out


def _load_one(data: Path, size: int, cache_dir: Path | None, progress) -> tuple[CaseArrays, list[str]]:
    meta_cols = ["case_id", "policy", "task", "init_source", "init_index", "subplan", "plans", "subplan_index", "kind",
                 "label"]
    meta = ds.read_cases(data, columns=meta_cols).to_pydict()
    if not meta["case_id"]:
        raise InvalidInput(f"{data} holds no cases; collect some with `seal verify collect`")
    # Case ids number starts, rounds and candidates, not weights: two VLA versions on the same fresh starts
    # write the same ids, so a case is also its policy's digest (and so is the image cache's name)
    digest = ds.collection_digest(ds.read_info(data))
    owner = [f"{p}@{digest}" if digest else p for p in meta["policy"]]
    fingerprint = hashlib.sha1("\n".join(([digest] if digest else []) + meta["case_id"]).encode()).hexdigest()[:16]
    cache = None if cache_dir is None else Path(cache_dir) / f"cache-{size}-{fingerprint}.npz"
    if cache is not None and cache.is_file():
        with np.load(cache) as f:
            first, final, wrist = f["first"], f["final"], f["wrist"]
    else:
        import pyarrow.parquet as pq

        views: list[list[np.ndarray]] = [[], [], []]
        paths = ds.shard_paths(data)
        for i, path in enumerate(paths):  # one shard's images in memory at a time
            table = pq.read_table(path, columns=list(ds.IMAGE_COLUMNS))
            for view, col in zip(views, ds.IMAGE_COLUMNS):
                view.append(_downsample(table.column(col).to_pylist(), size))
            if progress:
                progress("images", i + 1, len(paths))
        first, final, wrist = (np.concatenate(v) for v in views)
        if cache is not None:
            cache.parent.mkdir(parents=True, exist_ok=True)
            tmp = cache.with_name("." + cache.name)
            with open(tmp, "wb") as f:
                np.savez(f, first=first, final=final, wrist=wrist)
            tmp.replace(cache)
    context = [context_of(s, p, None if i < 0 else i)
               for s, p, i in zip(meta["subplan"], meta["plans"], meta["subplan_index"])]
    init_key = [init_key_of(t, s, i) for t, s, i in zip(meta["task"], meta["init_source"], meta["init_index"])]
    return CaseArrays(first, final, wrist, list(meta["subplan"]), context,
                      np.asarray(meta["label"], dtype=np.float32), list(meta["task"]), list(meta["kind"]),
                      init_key, list(meta["init_source"]), list(meta["policy"])), \
        [f"{p}|{c}" for p, c in zip(owner, meta["case_id"])]


def load_arrays(data: Path | list[Path], size: int, cache_dir: Path | None = None,
                progress=None) -> tuple[CaseArrays, str]:
    """Every case of one or more collections at ``size`` px, and a fingerprint of the data (its cases,
    in the order given). A case is its policy (with the weights' digest for a learned one) and case id:
    two collections made with different policies may number their cases alike, but the same case twice
    means a collection given twice."""
    dirs = [Path(data)] if isinstance(data, (str, Path)) else [Path(d) for d in data]
    parts = [_load_one(d, size, cache_dir, progress) for d in dirs]
    ids = [i for _, part_ids in parts for i in part_ids]
    if len(set(ids)) != len(ids):
        seen: dict[str, Path] = {}
        for d, (_, part_ids) in zip(dirs, parts):
            for i in part_ids:
                if i in seen:
                    raise InvalidInput(f"verification case {i.split('|', 1)[1]!r} ({i.split('|', 1)[0]} policy) is in "
                                       f"both {seen[i]} and {d}; give each collection once")
                seen[i] = d
    fingerprint = hashlib.sha1("\n".join(ids).encode()).hexdigest()[:16]
    if len(parts) == 1:
        return parts[0][0], fingerprint
    arrays = [a for a, _ in parts]
    cat = lambda name: np.concatenate([getattr(a, name) for a in arrays])  # noqa: E731
    join = lambda name: [x for a in arrays for x in getattr(a, name)]  # noqa: E731
    return CaseArrays(cat("first"), cat("final"), cat("wrist"), join("subplan"), join("context"), cat("label"),
                      join("task"), join("kind"), join("init_key"), join("source"),
                      join("policy")), fingerprint


def split(arrays: CaseArrays, cfg: VerifierTrainConfig) -> dict[str, np.ndarray]:
    """Indices of train / heldout_inits / heldout_tasks. Cases replayed from demonstrations
    (`seal verify from-demos`) are training data only: they never enter a held-out split (their
    starts and actions are not SEAL's), and those of held-out tasks are left out altogether."""
    parts = np.array([part_of(t, k, s, cfg) for t, k, s in zip(arrays.task, arrays.init_key, arrays.source)])
    tasks = sorted(set(arrays.task))
    unknown = [t for t in cfg.holdout_tasks if t not in tasks]
    if unknown:
        raise InvalidInput(f"--holdout-tasks {unknown} not in the data; its tasks: {', '.join(tasks)}")
    if not (parts == "train").any():
        raise InvalidInput("nothing left to train on after the held-out splits")
    return {name: np.flatnonzero(parts == name) for name in ("train", "heldout_inits", "heldout_tasks")}


def part_of(task: str, init_key: str, source: str, cfg: VerifierTrainConfig) -> str | None:
    """Which split one case falls in: train, heldout_tasks, heldout_inits, or None (a held-out
    task's case replayed from a demonstration: in no split). A case's split depends on the case
    alone (its task, its init state by hash, its source), never on the rest of the data."""
    demo = source == ds.DEMO_SOURCE
    if task in cfg.holdout_tasks:
        return None if demo else "heldout_tasks"
    h = int.from_bytes(hashlib.sha1(f"{cfg.seed}:{init_key}".encode()).digest()[:8], "big") / 2**64
    return "heldout_inits" if h < cfg.holdout_inits and not demo else "train"


def export_heldout(data: list[Path], out: Path, cfg: VerifierTrainConfig, *, train: bool = False) -> dict[str, int]:
    """Write the held-out parts of a training run's split as collections ``out/heldout_inits`` and
    ``out/heldout_tasks`` (shards copied row for row), so `seal bench verifier --data` scores any
    verifier, a VLM included, on exactly the cases a learned verifier was held out on. With
    ``train``, the rest too, as ``out/train``: for a collection the run did not train on (another
    policy's cases) that is a calibration set sharing no start and no task with the held-out parts,
    so a threshold picked on it is not tuned on them. (Off by default: for the run's own training
    data it would copy hundreds of MB for nothing.)"""
    import pyarrow.parquet as pq

    out = Path(out)
    counts = {"train": 0} if train else {}
    counts |= {"heldout_inits": 0, "heldout_tasks": 0}
    for d in data:
        ds.read_info(d)
        for path in ds.shard_paths(d):
            rows = pq.read_table(path).to_pylist()
            for part in counts:
                kept = [r for r in rows if part_of(r["task"], init_key_of(r["task"], r["init_source"], r["init_index"]),
                                                   r["init_source"], cfg) == part]
                if kept:  # shard names are unique within a collection, not across them
                    ds.write_shard(out / part, f"{Path(d).name}-{path.name}", kept)
                    counts[part] += len(kept)
    for part, n in counts.items():
        ds.write_info(out / part, {"collection": {"settings": {
            "what": f"{part} of `seal train verifier` (seed {cfg.seed}, --holdout-tasks "
                    f"{','.join(cfg.holdout_tasks) or '-'}, --holdout-inits {cfg.holdout_inits:g})",
            "from": [str(d) for d in data]}, "cases": n}})
    return counts


# ---- metrics ----------------------------------------------------------------------------------------------
def case_weights(labels: np.ndarray, train_idx: np.ndarray, cfg: VerifierTrainConfig,
                 passed_by_init: np.ndarray | None = None) -> np.ndarray:
    """The loss weight of each training case (aligned with ``train_idx``): 1 for a success,
    ``negative_weight`` for a failure, times ``hard_negative_weight`` for a failure the initial
    checkpoint passes (``passed_by_init``, aligned with ``train_idx``)."""
    failed = np.asarray(labels)[train_idx] < 0.5
    w = np.where(failed, cfg.negative_weight, 1.0)
    if passed_by_init is not None:
        w = np.where(failed & np.asarray(passed_by_init, bool), w * cfg.hard_negative_weight, w)
    return w.astype(np.float32)


def _predict(net, arrays: CaseArrays, idx: np.ndarray, vocab: WordVocab, max_words: int, batch: int = 256):
    probs = []
    net.eval()
    with torch.inference_mode():
        for s in range(0, len(idx), batch):
            b = idx[s:s + batch]
            probs.append(torch.sigmoid(net(*_tensors(arrays, b, vocab, max_words))).numpy())
    net.train()
    return np.concatenate(probs) if probs else np.zeros(0)


def evaluate(net, arrays, idx, vocab, max_words, threshold) -> dict | None:
    if len(idx) == 0:
        return None
    probs = _predict(net, arrays, idx, vocab, max_words)
    out = binary_metrics(arrays.label[idx] > 0.5, probs >= threshold)
    kinds = np.array(arrays.kind)[idx]
    out["per_kind"] = {k: binary_metrics(arrays.label[idx][kinds == k] > 0.5, (probs >= threshold)[kinds == k])
                       for k in ds.KINDS if (kinds == k).any()}
    return out


def score_runs(data: list[Path], runs: list[Path], cfg: VerifierTrainConfig, cache_dir: Path | None = None) -> dict:
    """Checkpoints scored on the held-out splits ``cfg`` makes of ``data`` (the split a training run
    with these settings would hold out), per split and per policy that made the cases: so runs
    trained on different data are compared on the same cases. Run -> "split/policy" -> metrics."""
    at_size: dict[int, tuple[CaseArrays, dict]] = {}  # the cases (and their split) at each input size
    out: dict[str, dict] = {}
    for run in runs:
        net, config, vocab = load_checkpoint(run)
        size = int(config["image_size"])
        if size not in at_size:
            arrays = load_arrays(data, size, cache_dir=cache_dir)[0]
            at_size[size] = arrays, split(arrays, cfg)
        arrays, parts = at_size[size]
        policies = np.array(arrays.policy)
        res = {}
        for part in ("heldout_inits", "heldout_tasks"):
            idx = parts[part]
            for policy in sorted(set(policies[idx])):
                m = evaluate(net, arrays, idx[policies[idx] == policy], vocab, int(config["max_words"]),
                             float(config["threshold"]))
                res[f"{part}/{policy}"] = m
        out[str(run)] = res
    return out


# ---- training ---------------------------------------------------------------------------------------------
def _tensors(arrays: CaseArrays, idx: np.ndarray, vocab: WordVocab, max_words: int, shifts=None, photo=None):
    views = [torch.from_numpy(a[idx]).float().div_(255.0) for a in (arrays.first, arrays.final, arrays.wrist)]
    if shifts is not None:  # one translation for both front views (keeps their difference), one for the wrist
        (ay, ax), (wy, wx) = shifts
        views[0] = _shift(views[0], ay, ax)
        views[1] = _shift(views[1], ay, ax)
        views[2] = _shift(views[2], wy, wx)
    if photo is not None:  # (brightness, contrast) factors: front pair, wrist
        (ab, ac), (wb, wc) = photo
        views = [_photometric(v, b, c) for v, b, c in zip(views, (ab, ab, wb), (ac, ac, wc))]
    sub = torch.from_numpy(vocab.encode([arrays.subplan[i] for i in idx], max_words))
    ctx = torch.from_numpy(vocab.encode([arrays.context[i] for i in idx], max_words))
    return (*views, sub, ctx)


def _shift(x, dy: np.ndarray, dx: np.ndarray):
    """Per-sample translation with edge padding."""
    pad = int(max(np.abs(dy).max(initial=0), np.abs(dx).max(initial=0)))
    if pad == 0:
        return x
    s = x.shape[-1]
    padded = F.pad(x, (pad, pad, pad, pad), mode="replicate")
    return torch.stack([padded[i, :, pad + dy[i]:pad + dy[i] + s, pad + dx[i]:pad + dx[i] + s]
                        for i in range(len(x))])


def _photometric(x, brightness: np.ndarray, contrast: np.ndarray):
    """Per-sample contrast about the image mean, then brightness; clipped to [0, 1]."""
    b = torch.as_tensor(brightness, dtype=x.dtype)[:, None, None, None]
    c = torch.as_tensor(contrast, dtype=x.dtype)[:, None, None, None]
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    return ((x - mean) * c + mean).mul_(b).clamp_(0.0, 1.0)


@torch.no_grad()
def _average_into(average, net, decay: float) -> None:
    """average <- decay * average + (1 - decay) * net. The caller ramps the decay up from ~0.1 over
    the first steps, so the random initial weights do not linger in the average."""
    for a, p in zip(average.parameters(), net.parameters()):
        a.lerp_(p, 1.0 - decay)


def _save_state(out: Path, obj: dict) -> None:
    tmp = out / f".{STATE}.tmp"
    torch.save(obj, tmp)
    tmp.replace(out / STATE)



def case_policies(datas: list[Path], arrays, train_idx: np.ndarray) -> dict:
    """Which policies' states the training cases come from (counts in the training split) and, per
    case directory, the policy that made it and its checkpoint digest where a learned policy did.
    Verifier and policy versions go together: when the VLA is re-shipped, this says whether the
    verifier ever saw it."""
    trained = collections.Counter(np.asarray(arrays.policy)[train_idx].tolist())
    sources = []
    for d in datas:
        info = ds.read_info(d).get("collection", {})
        sources.append({"data": str(d), "policy": info.get("policy") or info.get("settings", {}).get("policy"),
                        "policy_ckpt_digest": ds.collection_digest({"collection": info})})
    return {"train_cases_by_policy": dict(sorted(trained.items())), "sources": sources}


def _init_checkpoint(init_from: str | Path, cfg: VerifierTrainConfig):
    """(net, config, vocab, provenance) of the checkpoint a fine-tune starts from."""
    path = checkpoint_dir(init_from)
    net, config, vocab = load_checkpoint(path)
    provenance = {"path": str(path), "digest": CHECKPOINT.digest(path)}
    if int(config["image_size"]) != cfg.image_size:
        # The network is convolutional with global pooling, so the same weights read any input size:
        # a fine-tune may look closer (a place is a few pixels at 96 px) and relearn the scale.
        provenance["image_size_from"] = int(config["image_size"])
        config = {**config, "image_size": cfg.image_size}
        weights, net = net.state_dict(), build_net(config)
        net.load_state_dict(weights)
    return net, config, vocab, provenance


def grow_vocabulary(net, config: dict, vocab: WordVocab, texts) -> tuple[object, dict, WordVocab, list[str]]:
    """The network, config and vocabulary of a checkpoint with the words of ``texts`` it lacks added
    (sorted, at the end). Each new word's embedding starts as a copy of the unknown word's, so the
    grown network gives every input exactly the probability the checkpoint gave it (the new words
    read as unknown until training moves them apart). Returns the added words too."""
    added = sorted({w for t in texts for w in words(t)} - set(vocab.index))
    if not added:
        return net, config, vocab, []
    grown = WordVocab(vocab.tokens + added)
    config = {**config, "vocab": grown.tokens}
    weights = net.state_dict()
    table = weights["embed.weight"]
    weights["embed.weight"] = torch.cat([table, table[1:2].expand(len(added), -1)])  # row 1: the unknown word
    net = build_net(config)
    net.load_state_dict(weights)
    return net, config, grown, added


def train_verifier(data: Path | list[Path], out: Path, cfg: VerifierTrainConfig, *, progress=None, threads: int | None = 1,
                   command: str = "", init_from: str | Path | None = None) -> dict:
    """Train (or continue training) into ``out``; returns the summary written to metrics.json.

    ``progress(stage, done, total, info)``: stage "load" then "train".
    ``init_from``: a verifier checkpoint to fine-tune (e.g. the shipped one on the steered policy's own
    cases): its network and threshold are kept, and its vocabulary grows by the training cases' words
    it lacks (`grow_vocabulary`; listed in the manifest's ``init_from.added_words``), so a fine-tune
    learns the words its start never saw (task-level instructions: "both", "put", ...)."""
    # (the settings were checked when cfg was made: bad ones fail before the images are decoded)
    if cfg.hard_negative_weight != 1.0 and not init_from:
        raise InvalidInput("--hard-negative-weight weighs the failed cases a starting checkpoint passes; give one "
                           "with --init-from (or leave the weight at 1)")
    if threads:
        torch.set_num_threads(threads)
    out = Path(out)
    datas = [Path(data)] if isinstance(data, (str, Path)) else [Path(d) for d in data]
    arrays, fingerprint = load_arrays(datas, cfg.image_size, cache_dir=out,
                                      progress=(lambda s, d, t: progress("load", d, t, "")) if progress else None)
    parts = split(arrays, cfg)
    out.mkdir(parents=True, exist_ok=True)  # not before: data that cannot be used leaves no empty run directory
    train_idx = parts["train"]
    state_path = out / STATE
    init = _init_checkpoint(init_from, cfg) if init_from else None
    if state_path.is_file():
        state = torch.load(state_path, weights_only=True)
        saved = json.loads(state["identity"])
        if saved != cfg.identity() or state["data"] != fingerprint:
            raise InvalidInput(f"{out} was trained with other settings or data (saved {saved}, data {state['data']}; "
                               f"now {cfg.identity()}, data {fingerprint}); use another --out")
        if state.get("init_digest") != (init[3]["digest"] if init else None):
            raise InvalidInput(f"{out} was started from {state.get('init_digest') or 'scratch'}, not from "
                               f"{init[3]['digest'] if init else 'scratch'}; use another --out")
        net, config, vocab = load_checkpoint(out)
        step = int(state["step"])
        average = None
        if cfg.ema:  # the checkpoint is the average; the raw weights are in the state
            average, net = net, build_net(config)
            net.load_state_dict(state["raw"])
    elif init:
        texts = [arrays.subplan[i] for i in train_idx] + [arrays.context[i] for i in train_idx]
        net, config, vocab, _ = grow_vocabulary(*init[:3], texts)
        step, state = 0, None
        average = copy.deepcopy(net) if cfg.ema else None
    else:
        vocab = WordVocab.build([arrays.subplan[i] for i in train_idx] + [arrays.context[i] for i in train_idx])
        config = default_config(vocab, cfg.image_size)
        torch.manual_seed(cfg.draw_seed)
        net = build_net(config)
        step, state = 0, None
        average = copy.deepcopy(net) if cfg.ema else None
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    if state is not None:
        opt.load_state_dict(state["optimizer"])
    max_words, threshold = int(config["max_words"]), float(config["threshold"])
    judged = average if cfg.ema else net  # what is evaluated and saved as the checkpoint
    if len(train_idx) < 2:
        raise InvalidInput(f"only {len(train_idx)} training case(s); collect more")

    sources = case_policies(datas, arrays, train_idx)
    if init:  # the same list on a resumed run: what the training cases have that the start lacked
        added = sorted(set(vocab.index) - set(init[2].index))
        sources["init_from"] = init[3] | {"added_words": added}

    def summary(final: bool) -> dict:
        return {"step": step, "data": ",".join(map(str, datas)), "data_fingerprint": fingerprint,
                "case_policies": sources,
                "split": {k: int(len(v)) for k, v in parts.items()},
                "holdout_tasks": list(cfg.holdout_tasks), "holdout_inits": cfg.holdout_inits,
                "train": evaluate(judged, arrays, train_idx[:2000], vocab, max_words, threshold) if final else None,
                "heldout_inits": evaluate(judged, arrays, parts["heldout_inits"], vocab, max_words, threshold),
                "heldout_tasks": evaluate(judged, arrays, parts["heldout_tasks"], vocab, max_words, threshold)}

    def checkpoint(manifest: dict | None = None) -> None:
        config["training"] = {"step": step, "data_fingerprint": fingerprint, "config": cfg.identity()}
        save_checkpoint(out, judged, config, manifest or {"step": step, "data": ",".join(map(str, datas)),
                                                          "data_fingerprint": fingerprint, "case_policies": sources})
        _save_state(out, {"identity": json.dumps(cfg.identity()), "data": fingerprint, "step": step,
                          "optimizer": opt.state_dict(), "init_digest": init[3]["digest"] if init else None}
                    | ({"raw": net.state_dict()} if cfg.ema else {}))

    passed = None
    if cfg.hard_negative_weight != 1.0:  # the start's own verdicts, at its own threshold
        passed = _predict(init[0], arrays, train_idx, init[2], int(init[1]["max_words"])) >= float(init[1]["threshold"])
    weights = case_weights(arrays.label, train_idx, cfg, passed_by_init=passed)
    if passed is not None:
        sources["hard_negatives"] = int((passed & (arrays.label[train_idx] < 0.5)).sum())
    weight_of_case = np.ones(len(arrays.label), np.float32)
    weight_of_case[train_idx] = weights
    net.train()
    last_save = time.monotonic()
    t0, s0, losses = time.perf_counter(), step, []
    with open(out / METRICS, "a") as log:
        while step < cfg.steps:
            rng = np.random.default_rng([cfg.draw_seed, step])
            idx = train_idx[rng.integers(0, len(train_idx), min(cfg.batch_size, len(train_idx)))]
            b = len(idx)
            shifts = (tuple(rng.integers(-cfg.shift, cfg.shift + 1, (2, b))),
                      tuple(rng.integers(-cfg.shift, cfg.shift + 1, (2, b)))) if cfg.shift else None
            torch.manual_seed(cfg.draw_seed * 1_000_003 + step)
            photo = (tuple(rng.uniform(1 - cfg.jitter, 1 + cfg.jitter, (2, b))),
                     tuple(rng.uniform(1 - cfg.jitter, 1 + cfg.jitter, (2, b)))) if cfg.jitter else None
            for group in opt.param_groups:
                group["lr"] = cfg.lr_at(step)
            logits = net(*_tensors(arrays, idx, vocab, max_words, shifts, photo))
            w = torch.from_numpy(weight_of_case[idx])
            loss = (F.binary_cross_entropy_with_logits(logits, torch.from_numpy(arrays.label[idx]), reduction="none")
                    * w).sum() / w.sum()
            opt.zero_grad()
            loss.backward()
            opt.step()
            step += 1
            if cfg.ema:
                _average_into(average, net, min(cfg.ema, (1 + step) / (10 + step)))
            losses.append(loss.item())
            info = f"loss {np.mean(losses[-20:]):.4f}"
            if step % cfg.log_every == 0 or step == cfg.steps:
                row = {"step": step, "loss": round(float(np.mean(losses[-cfg.log_every:])), 5),
                       "steps_per_s": round((step - s0) / (time.perf_counter() - t0), 2)}
                if step % cfg.eval_every == 0 or step == cfg.steps:
                    s = summary(final=False)
                    row |= {k: {m: s[k][m] for m in ("accuracy", "precision", "recall", "f1")} if s[k] else None
                            for k in ("heldout_inits", "heldout_tasks")}
                log.write(json.dumps(row) + "\n")
                log.flush()
            if time.monotonic() - last_save >= cfg.save_every_s:
                checkpoint()
                last_save = time.monotonic()
            if progress:
                progress("train", step, cfg.steps, info)
    result = summary(final=True)
    checkpoint(manifest_of(result, command))
    (out / "metrics.json").write_text(json.dumps(result, indent=1))
    plot_loss(out)
    return result


def average_runs(runs: list[Path], out: Path, command: str = "") -> dict:
    """One checkpoint whose weights are the mean of ``runs``' (a uniform "model soup"): runs that
    fine-tuned one checkpoint on the same data with different training seeds share a basin, so their
    average is a network of the same shape and cost that is usually at least as good as each, and
    steadier than any one seed. Runs that do not share the architecture, vocabulary and threshold are
    refused. The manifest names every ingredient (path and digest) and carries the first one's data
    provenance (``case_policies``), which the ingredients are checked to share."""
    from seal.checkpoint import read_manifest
    from seal.verify.learned import KIND

    if len(runs) < 2:
        raise InvalidInput(f"averaging needs at least two runs, got {len(runs)}")
    loaded = [load_checkpoint(r) for r in runs]
    first_config = loaded[0][1]
    for run, (_, config, _) in zip(runs[1:], loaded[1:]):
        for key in (*ARCH_KEYS, "threshold"):
            if config.get(key) != first_config.get(key):
                raise InvalidInput(f"{run} differs from {runs[0]} in {key!r}: only runs of one architecture, "
                                   f"vocabulary and threshold (fine-tunes of one checkpoint) can be averaged")
    manifests = [read_manifest(checkpoint_dir(r), kind=KIND) for r in runs]
    fingerprints = {m.get("data_fingerprint") for m in manifests}
    if len(fingerprints) > 1:
        raise InvalidInput(f"the runs were trained on different data ({sorted(map(str, fingerprints))}); average "
                           f"runs of one recipe that differ only in their training seed")
    net = loaded[0][0]
    states = [n.state_dict() for n, _, _ in loaded]
    with torch.no_grad():
        for name, tensor in net.state_dict().items():
            if tensor.is_floating_point():
                tensor.copy_(torch.stack([s[name] for s in states]).mean(0))
    ingredients = [{"path": str(checkpoint_dir(r)), "digest": CHECKPOINT.digest(checkpoint_dir(r)),
                    "heldout_inits": m.get("heldout_inits")} for r, m in zip(runs, manifests)]
    config = {k: v for k, v in first_config.items() if k != "training"} | {"training": {"average_of": ingredients}}
    manifest = {"average_of": ingredients, "data": manifests[0].get("data"),
                "data_fingerprint": manifests[0].get("data_fingerprint"),
                "case_policies": manifests[0].get("case_policies"), "split": manifests[0].get("split"),
                "holdout_tasks": manifests[0].get("holdout_tasks"), "command": command}
    save_checkpoint(Path(out), net, config, manifest)
    return {"out": str(Path(out).resolve()), "average_of": ingredients}


def manifest_of(result: dict, command: str = "") -> dict:
    """What a finished run's manifest says beside its files' digests: the data it was trained on and
    its held-out figures. Shipping = copying model.safetensors, config.json and manifest.json into
    ``seal/verify/checkpoints/learned/``."""

    def headline(m):
        return None if not m else {k: m[k] for k in ("n", "accuracy", "precision", "recall", "f1")}

    return {"step": result["step"], "data": result["data"], "data_fingerprint": result["data_fingerprint"],
            "case_policies": result["case_policies"],
            "split": result["split"], "holdout_tasks": result["holdout_tasks"],
            "heldout_inits": headline(result["heldout_inits"]), "heldout_tasks": headline(result["heldout_tasks"]),
            "command": command or "seal train verifier (see docs/verifier.md)"}


def plot_loss(out: Path) -> Path | None:
    rows = [json.loads(line) for line in (out / METRICS).read_text().splitlines() if line.strip()]
    if not rows:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot([r["step"] for r in rows], [r["loss"] for r in rows], label="training loss (BCE)")
    for key, style in (("heldout_inits", "o-"), ("heldout_tasks", "s-")):
        pts = [(r["step"], r[key]["accuracy"]) for r in rows if r.get(key)]
        if pts:
            ax.plot(*zip(*pts), style, label=f"{key.replace('_', ' ')} accuracy")
    ax.set_xlabel("step")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path = out / "loss_curve.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
