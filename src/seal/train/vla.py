"""`seal train vla`: annotated demonstrations -> a reasoning VLA (or its non-reasoning twin).

Data. The annotation sidecar (`seal annotate`) names its source dataset; every annotated episode
is decoded ONCE into a frame cache at the model's resolution (``CACHE/agent.u8`` and
``wrist.u8``: uint8 memmaps (N, S, S, 3); ``frames.npz``: states, actions, episode bounds;
``cache.json``, written last, says what the cache holds). A later run or a resume with the same
dataset, episodes and resolution reuses it. One training sample is one frame t of a training
episode: both images and the state at t, the instruction, the reasoning label in force at t
(`seal.annotate.align.label_at` over the annotated plans and critical frames: the same function
that wrote the sidecar) and the chunk ``actions[t : t + 16]`` (padded steps masked out).

Think samples. The policy should say <think> once the sub-plan it is acting on is done. For the
frames ``[c, c + 5)`` right after a sub-goal first held at frame c, a sample with the reasoning
that was in force *before* c (its sub-plan now done) is labelled think=1; every ordinary sample
(with the current reasoning) is labelled think=0. A fixed share of each batch
(``think_fraction``) are such samples, since they are otherwise ~3% of frames; they train only
the think head (their actions belong to the next sub-plan and their text is stale).

Augmentation. Each image is shifted by up to ``shift`` pixels (edge-replicated padding, then a
random crop back to size, DrQ's random shift), independently per camera and sample. At 64 px
a 4-pixel shift is ~6% of the frame: enough to stop the encoder from keying on exact pixel
positions, small enough to keep the gripper and objects in view.

Loop. AdamW with a linear warm-up and a cosine decay (the learning rate is a function of the
step, so a resume needs no scheduler state); bf16 autocast on CPU when ``bf16`` is set (measured
faster here, docs/performance.md); gradient clipping at 1. Every ``save_minutes`` (and at the
end, and on Ctrl-C) the run directory's ``checkpoint/`` is replaced atomically with: the model
(a loadable VLA checkpoint, `seal.policies.vla.checkpoint`), the optimizer state, the sampler's
and the generators' states and the step (``train_state.safetensors`` + ``train_state.json``).
Running again on the run directory resumes exactly: the loss sequence is the one an
uninterrupted run would have logged (tested). Held-out episodes (split by episode, seeded) are
evaluated every ``eval_every`` steps: action MSE of sampled chunks against the recorded ones and
sub-plan exact match (greedy-decoded "Now I need to do" field against the label). Metrics go
to ``metrics.jsonl``; ``curves.png`` plots them.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import subprocess
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from seal.errors import InvalidInput
from seal.policies.base import ACTION_HORIZON, PREDICT_HORIZON
from seal.policies.vla.checkpoint import load_checkpoint, save_checkpoint
from seal.policies.vla.locate import RUN_CHECKPOINT
from seal.policies.vla.model import ACTION_DIM, STATE_DIM, VLAConfig, VLAModel, count_parameters
from seal.policies.vla.preprocess import instruction_ids, reasoning_ids, resize_images
from seal.policies.vla.tokenizer import VLATokenizer, project_texts, train_tokenizer

METRICS = "metrics.jsonl"
CURVES = "curves.png"
TOKENIZER = "tokenizer.json"
STATE_TENSORS, STATE_JSON = "train_state.safetensors", "train_state.json"
CACHE_INFO = "cache.json"
# settings that do not change what is learned: a resume may change them
_RESUMABLE = ("steps", "save_minutes", "eval_every", "eval_samples", "log_every", "device", "threads")


@dataclass(frozen=True)
class TrainConfig:
    steps: int = 9000
    batch_size: int = 32
    lr: float = 3e-4
    warmup: int = 300
    weight_decay: float = 0.01
    grad_clip: float = 1.0
    seed: int = 0
    holdout: float = 0.1  # share of annotated episodes held out (split by episode)
    shift: int = 4  # random-shift augmentation, pixels at the model's resolution
    think_fraction: float = 0.125  # share of each batch that are think samples (reasoning model only)
    # share of ordinary samples whose instruction is left out (reasoning model only): the action expert
    # must then read the task from the sub-plan text, so its actions follow the reasoning, not the prompt
    instruction_dropout: float = 0.0
    # models whose actions do not read the instruction (VLAConfig.actions_read_instruction=False): the share
    # of ordinary samples that train the reasoning text, with the instruction; the others train the action
    # chunk and the think flag with it left out, as the model runs them. Think samples leave it out too.
    text_share: float = 0.25
    # bf16 autocast; None: on where it pays (a GPU, or a CPU with native bf16 units: `native_bf16`). On a
    # CPU without them (AVX-512 but no avx512_bf16/AMX) it is emulated: ~5x slower per step, measured
    bf16: bool | None = None
    threads: int = 1  # torch intra-op threads (on a shared 2-core machine, 1 was fastest)
    device: str = "cpu"
    save_minutes: float = 10.0
    eval_every: int = 500
    eval_samples: int = 64  # held-out chunk starts per evaluation
    log_every: int = 10


# ------------------------------------------------------------------------------------------ data


@dataclass
class FrameCache:
    """Every frame of the cached episodes at the model's resolution, in episode order."""

    agent: np.ndarray  # (N, S, S, 3) uint8 memmap
    wrist: np.ndarray
    states: np.ndarray  # (N, 8) float32
    actions: np.ndarray  # (N, 7) float32
    episodes: list[int]  # dataset episode index of each cached episode
    starts: np.ndarray  # (E,) first global frame of each
    lengths: np.ndarray  # (E,)
    info: dict

    def position(self, episode: int) -> int:
        return self.episodes.index(episode)


def build_cache(reader, episodes: list[int], cache: Path, image_size: int, progress=None) -> FrameCache:
    """Decode the episodes' two videos once into uint8 memmaps at ``image_size`` (reused when
    ``cache/cache.json`` says it holds exactly these episodes of this dataset at this size)."""
    from seal.datasets.lerobot import ACTION_KEY, AGENT_VIDEO_KEY, STATE_KEY, WRIST_VIDEO_KEY, fixed_list_to_numpy

    cache = Path(cache)
    want = {"source": str(Path(reader.root).resolve()), "episodes": list(map(int, episodes)),
            "image_size": int(image_size), "format": 1}
    info_path = cache / CACHE_INFO
    if info_path.is_file():
        info = json.loads(info_path.read_text())
        if {k: info.get(k) for k in want} == want:
            return _open_cache(cache, info)
        raise InvalidInput(f"frame cache {cache} holds other data ({info.get('source')}, {len(info.get('episodes', []))} "
                           f"episodes at {info.get('image_size')} px); give another --cache directory or delete it")
    cache.mkdir(parents=True, exist_ok=True)
    lengths = [reader.frames(e).num_rows for e in episodes]
    n = int(sum(lengths))
    if n == 0:
        raise InvalidInput("no frames to train on: the selected episodes are empty")
    shape = (n, image_size, image_size, 3)
    agent = np.lib.format.open_memmap(cache / "agent.npy", mode="w+", dtype=np.uint8, shape=shape)
    wrist = np.lib.format.open_memmap(cache / "wrist.npy", mode="w+", dtype=np.uint8, shape=shape)
    states = np.zeros((n, STATE_DIM), np.float32)
    actions = np.zeros((n, ACTION_DIM), np.float32)
    pos = 0
    for k, (e, length) in enumerate(zip(episodes, lengths)):
        table = reader.frames(e)
        for key, out in ((AGENT_VIDEO_KEY, agent), (WRIST_VIDEO_KEY, wrist)):
            frames = reader.video(e, key)
            if len(frames) != length:
                raise InvalidInput(f"episode {e}: video {key!r} has {len(frames)} frames, the data {length} rows")
            out[pos:pos + length] = resize_images(frames, image_size)
        states[pos:pos + length] = fixed_list_to_numpy(table.column(STATE_KEY))
        actions[pos:pos + length] = fixed_list_to_numpy(table.column(ACTION_KEY))
        pos += length
        if progress:
            progress(k + 1, len(episodes))
    agent.flush()
    wrist.flush()
    np.savez(cache / "frames.npz", states=states, actions=actions, starts=np.cumsum([0, *lengths[:-1]]),
             lengths=np.asarray(lengths))
    info = {**want, "frames": n}
    tmp = info_path.with_suffix(".tmp")
    tmp.write_text(json.dumps(info, indent=2))
    os.replace(tmp, info_path)  # the commit: a cache without it is rebuilt
    return _open_cache(cache, info)


def _open_cache(cache: Path, info: dict) -> FrameCache:
    z = np.load(cache / "frames.npz")
    return FrameCache(agent=np.load(cache / "agent.npy", mmap_mode="r"), wrist=np.load(cache / "wrist.npy", mmap_mode="r"),
                      states=z["states"], actions=z["actions"], episodes=list(info["episodes"]), starts=z["starts"],
                      lengths=z["lengths"], info=info)


@dataclass
class Labels:
    """Per-frame labels over a FrameCache, and the tokenized texts they point to."""

    texts: list[str]  # reasoning texts, indexed by `reason`
    instructions: list[str]
    reason: np.ndarray  # (N,) index into texts: the label in force at each frame
    instruction: np.ndarray  # (N,) index into instructions
    now: list[str]  # per text: its "Now I need to do" field
    think_frames: np.ndarray  # (M,) global frames right after a sub-goal first held
    think_reason: np.ndarray  # (M,) the stale label (in force before that sub-goal held)
    # DAgger sources (`seal demos dagger`): the teacher's chunk at each frame, and whether the teacher
    # had an answer there at all (frames without one give no action or text sample, only think ones)
    chunks: np.ndarray | None = None  # (N, PREDICT_HORIZON, 7)
    usable: np.ndarray | None = None  # (N,) bool; None: every frame
    chunk_steps: np.ndarray | None = None  # (N,) how many leading steps of each chunk are labels
    # per text: whether it is ever a target (the policy's own stale texts only condition think samples,
    # whose text loss is masked, so one too long for the reasoning segment is cut, not refused)
    target: np.ndarray | None = None


class _Texts:
    """Distinct reasoning texts and instructions, numbered in the order they first appear."""

    def __init__(self):
        self.ids: dict[str, int] = {}
        self.nows: list[str] = []  # per text: its "Now I need to do" field
        self.instructions: dict[str, int] = {}

    def text(self, text: str, now: str) -> int:
        if text not in self.ids:
            self.ids[text] = len(self.ids)
            self.nows.append(now)
        return self.ids[text]

    def instruction(self, text: str) -> int:
        return self.instructions.setdefault(text, len(self.instructions))

    def labels(self, reason, instruction, think_frames, think_reason, **extra) -> Labels:
        target = np.zeros(len(self.ids), bool)
        target[np.unique(reason)] = True
        return Labels(list(self.ids), list(self.instructions), reason, instruction, self.nows,
                      np.asarray(think_frames, np.int64), np.asarray(think_reason, np.int64), target=target, **extra)


def make_labels(cache: FrameCache, records: dict[int, dict], root: Path | None = None) -> Labels:
    """Per-frame labels of the cached episodes: from plans + critical moments (demonstrations), or
    read per frame from ``root``'s label files (DAgger episodes, ``frame_labels`` records)."""
    from seal.annotate.align import label_at

    per_frame = {bool(records[e].get("frame_labels")) for e in cache.episodes}
    if len(per_frame) > 1:
        raise InvalidInput("an annotation directory mixes DAgger episodes with demonstrations; give them as two "
                           "--annotations sources")
    if per_frame == {True}:
        return _frame_labels(cache, records, root)
    texts = _Texts()
    n = len(cache.states)
    reason = np.zeros(n, np.int64)
    instruction = np.zeros(n, np.int64)
    think_frames, think_reason = [], []

    def text_id(r) -> int:
        return texts.text(r.text(), r.now)

    for e, start, length in zip(cache.episodes, cache.starts, cache.lengths):
        record = records[e]
        plans = list(record["plans"])
        critical = [int(m["dataset_frame"]) for m in record["critical_moments"]]
        instruction[start:start + length] = texts.instruction(record["instruction"])
        for t in range(length):
            reason[start + t] = text_id(label_at(plans, critical, t))
        for c in critical:
            if 1 <= c < length:
                stale = text_id(label_at(plans, critical, c - 1))
                for t in range(c, min(c + ACTION_HORIZON, length)):
                    if reason[start + t] != stale:
                        think_frames.append(start + t)
                        think_reason.append(stale)
    return texts.labels(reason, instruction, think_frames, think_reason)


def _frame_labels(cache: FrameCache, records: dict[int, dict], root: Path | None) -> Labels:
    """Labels of DAgger episodes: the teacher's text and chunk at every frame; a think sample (the
    policy's own, stale text -> think) wherever the policy's sub-plan was not the teacher's."""
    from seal.dagger import read_frame_labels
    from seal.policies.base import parse_reasoning

    if root is None:
        raise InvalidInput("DAgger labels need the annotation directory they live in")
    texts = _Texts()
    n = len(cache.states)
    reason = np.zeros(n, np.int64)
    instruction = np.zeros(n, np.int64)
    chunks = np.zeros((n, PREDICT_HORIZON, ACTION_DIM), np.float32)
    usable = np.zeros(n, bool)
    chunk_steps = np.zeros(n, np.int64)
    think_frames, think_reason = [], []

    def text_id(t: str) -> int:
        return texts.text(t, parse_reasoning(t).now)

    for e, start, length in zip(cache.episodes, cache.starts, cache.lengths):
        lab = read_frame_labels(root, records[e])
        if len(lab["reasoning"]) != length:
            raise InvalidInput(f"{root}: episode {e} has {len(lab['reasoning'])} labels for {length} frames")
        instruction[start:start + length] = texts.instruction(records[e]["instruction"])
        for t in range(length):
            reason[start + t] = text_id(lab["reasoning"][t])
            if lab["think"][t]:
                think_frames.append(start + t)
                think_reason.append(text_id(lab["vla_reasoning"][t]))
        chunks[start:start + length] = lab["chunks"]
        usable[start:start + length] = lab["valid"]
        chunk_steps[start:start + length] = lab["chunk_steps"]
    return texts.labels(reason, instruction, think_frames, think_reason, chunks=chunks, usable=usable,
                        chunk_steps=chunk_steps)


class Batcher:
    """Turns frame indices into model batches (tokenized once, gathered per batch)."""

    def __init__(self, cache: FrameCache, labels: Labels, tok: VLATokenizer, cfg: VLAConfig):
        self.cache, self.labels, self.cfg = cache, labels, cfg
        ins = [instruction_ids(tok, t, cfg.max_instruction_tokens) for t in [*labels.instructions, ""]]
        self.no_instruction = len(labels.instructions)  # the empty one, last
        self.instr_ids = np.stack([i for i, _ in ins])
        self.instr_valid = np.stack([v for _, v in ins])
        if cfg.reasoning:
            strict = np.ones(len(labels.texts), bool) if labels.target is None else labels.target
            rs = [reasoning_ids(tok, t, cfg.max_reasoning_tokens, strict=bool(s)) for t, s in zip(labels.texts, strict)]
            self.reason_ids = np.stack([r[0] for r in rs])
            self.reason_valid = np.stack([r[1] for r in rs])
            self.act_index = np.asarray([r[2] for r in rs], np.int64)
        # global frame -> first frame after its episode (to cut action windows)
        ends = np.zeros(len(cache.states), np.int64)
        for start, length in zip(cache.starts, cache.lengths):
            ends[start:start + length] = start + length
        self.ends = ends

    def batch(self, frames: np.ndarray, reason: np.ndarray, think: np.ndarray, shift: int = 0,
              gen: torch.Generator | None = None, device: str = "cpu", drop: np.ndarray | None = None,
              text: np.ndarray | None = None) -> dict:
        """``drop``: per sample, whether its instruction is replaced by an empty one. ``text`` (models whose
        actions do not read the instruction): per sample, whether it trains the text, with the instruction,
        rather than the chunk and think flag without it (``drop`` is then its complement)."""
        if text is not None:
            drop = ~text
        order = np.argsort(frames, kind="stable")  # memmap reads in file order, then back
        agent = np.empty((len(frames), *self.cache.agent.shape[1:]), np.uint8)
        wrist = np.empty_like(agent)
        agent[order] = self.cache.agent[frames[order]]
        wrist[order] = self.cache.wrist[frames[order]]
        agent_t, wrist_t = torch.from_numpy(agent), torch.from_numpy(wrist)
        if shift:
            agent_t, wrist_t = random_shift(agent_t, shift, gen), random_shift(wrist_t, shift, gen)
        if self.labels.chunks is not None:  # the teacher's whole chunk at this frame
            actions = self.labels.chunks[frames]
            valid = np.arange(PREDICT_HORIZON)[None] < self.labels.chunk_steps[frames][:, None]
        else:  # the recorded actions from this frame on
            window = frames[:, None] + np.arange(PREDICT_HORIZON)[None]
            valid = window < self.ends[frames][:, None]
            actions = self.cache.actions[np.minimum(window, self.ends[frames][:, None] - 1)]  # padding repeats the last
        instr = self.labels.instruction[frames]
        if drop is not None:  # the sub-plan alone must carry the task: the instruction left out
            instr = np.where(drop, self.no_instruction, instr)
        out = {"agent": agent_t, "wrist": wrist_t, "state": torch.from_numpy(self.cache.states[frames]),
               "instr_ids": torch.from_numpy(self.instr_ids[instr]),
               "instr_valid": torch.from_numpy(self.instr_valid[instr]),
               "actions": torch.from_numpy(actions), "action_valid": torch.from_numpy(valid),
               "action_mask": torch.from_numpy(~think), "text_mask": torch.from_numpy(~think),
               "think": torch.from_numpy(think.astype(np.float32))}
        if text is not None:  # each sample trains what the model computes from the prefix it was given
            out |= {"text_mask": torch.from_numpy(text), "action_mask": torch.from_numpy(~text & ~think),
                    "think_mask": torch.from_numpy(~text)}
        if self.cfg.reasoning:
            out |= {"reason_ids": torch.from_numpy(self.reason_ids[reason]),
                    "reason_valid": torch.from_numpy(self.reason_valid[reason]),
                    "act_index": torch.from_numpy(self.act_index[reason])}
        return {k: v.to(device) for k, v in out.items()}


def random_shift(images: torch.Tensor, pad: int, gen: torch.Generator | None) -> torch.Tensor:
    """(N, H, W, 3) uint8: pad each image by ``pad`` (edge) and crop back at a random offset."""
    n, h, w, _ = images.shape
    padded = torch.nn.functional.pad(images.permute(0, 3, 1, 2).float(), (pad,) * 4, mode="replicate")
    dx = torch.randint(0, 2 * pad + 1, (n,), generator=gen)
    dy = torch.randint(0, 2 * pad + 1, (n,), generator=gen)
    rows = (dy[:, None] + torch.arange(h)[None])[:, :, None].expand(n, h, w)
    cols = (dx[:, None] + torch.arange(w)[None])[:, None, :].expand(n, h, w)
    out = padded.permute(0, 2, 3, 1)[torch.arange(n)[:, None, None], rows, cols]
    return out.round().to(torch.uint8)


def synthetic_batch(cfg: VLAConfig, batch: int, seed: int = 0) -> dict:
    """A batch of the real shapes with random content (benchmarks, tests)."""
    g = torch.Generator().manual_seed(seed)
    s, li, lr = cfg.image_size, cfg.max_instruction_tokens, cfg.max_reasoning_tokens
    lengths = torch.randint(lr // 2, lr, (batch,), generator=g)
    out = {"agent": torch.randint(0, 256, (batch, s, s, 3), dtype=torch.uint8, generator=g),
           "wrist": torch.randint(0, 256, (batch, s, s, 3), dtype=torch.uint8, generator=g),
           "state": torch.randn(batch, STATE_DIM, generator=g),
           "instr_ids": torch.randint(6, cfg.vocab_size, (batch, li), generator=g),
           "instr_valid": torch.arange(li)[None].expand(batch, -1) < li // 2,
           "actions": torch.rand(batch, PREDICT_HORIZON, ACTION_DIM, generator=g) * 2 - 1,
           "action_valid": torch.ones(batch, PREDICT_HORIZON, dtype=torch.bool),
           "action_mask": torch.ones(batch, dtype=torch.bool), "text_mask": torch.ones(batch, dtype=torch.bool),
           "think": (torch.rand(batch, generator=g) < 0.125).float()}
    if cfg.reasoning:
        out |= {"reason_ids": torch.randint(6, cfg.vocab_size, (batch, lr), generator=g),
                "reason_valid": torch.arange(lr)[None] < lengths[:, None], "act_index": lengths - 1}
    return out


# ------------------------------------------------------------------------------------------ state


def learning_rate(cfg: TrainConfig, step: int) -> float:
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    progress = min(1.0, (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup))
    return cfg.lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * progress)))


def _code_version() -> str:
    try:
        root = Path(__file__).resolve().parents[3]
        out = subprocess.run(["git", "-C", str(root), "describe", "--always", "--dirty"], capture_output=True,
                             text=True, timeout=5)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _optimizer_tensors(opt: torch.optim.Optimizer) -> tuple[dict, dict]:
    sd = opt.state_dict()
    tensors = {f"opt.{i}.{k}": v.detach().cpu().contiguous() for i, st in sd["state"].items() for k, v in st.items()}
    return tensors, {"param_groups": sd["param_groups"]}


def _load_optimizer(opt: torch.optim.Optimizer, tensors: dict, meta: dict) -> None:
    state: dict = {}
    for name, value in tensors.items():
        if name.startswith("opt."):
            _, i, k = name.split(".", 2)
            state.setdefault(int(i), {})[k] = value
    opt.load_state_dict({"state": state, "param_groups": meta["param_groups"]})


@dataclass
class RunState:
    step: int
    rng: np.random.Generator  # which frames each batch takes
    gen: torch.Generator  # augmentation shifts, flow noise and times


def save_run(run: Path, model: VLAModel, tok: VLATokenizer, opt, state: RunState, cfg: TrainConfig, fingerprint: str,
             manifest: dict) -> None:
    """Replace ``run/checkpoint`` atomically (a new directory is renamed over the old one)."""
    from safetensors.torch import save_file

    final, tmp, old = run / RUN_CHECKPOINT, run / (RUN_CHECKPOINT + ".tmp"), run / (RUN_CHECKPOINT + ".old")
    shutil.rmtree(tmp, ignore_errors=True)
    save_checkpoint(tmp, model, tok, {**manifest, "step": state.step})
    tensors, meta = _optimizer_tensors(opt)
    tensors["torch_generator"] = state.gen.get_state()
    save_file(tensors, str(tmp / STATE_TENSORS))
    (tmp / STATE_JSON).write_text(json.dumps({"step": state.step, "config": asdict(cfg), "data": fingerprint,
                                              "numpy_rng": state.rng.bit_generator.state, **meta}, indent=1))
    if final.exists():
        shutil.rmtree(old, ignore_errors=True)
        os.replace(final, old)
    os.replace(tmp, final)
    shutil.rmtree(old, ignore_errors=True)


def _resume_dir(run: Path) -> Path | None:
    for name in (RUN_CHECKPOINT, RUN_CHECKPOINT + ".old"):  # .old: a crash between the two renames
        if (run / name / STATE_JSON).is_file():
            return run / name
    return None


# ------------------------------------------------------------------------------------------ training
def _succeeded(meta: dict) -> bool:
    """A demonstration's own success flag; datasets that carry none (other recorders) count as successes."""
    return bool(meta.get("meta", meta).get("success", True))




def recorded_render(metas: list[dict]) -> dict:
    """The render model the demonstrations were recorded in ({"mode", "fast_version"}): a pixel
    policy is evaluated in the same one (`MethodSpec` defaults to it). Mixed recordings are refused:
    the policy would be trained on two kinds of pixels and evaluated in one."""
    # recorders nest their own fields under "meta" in episodes.jsonl (LeRobot keeps the top level)
    inner = [m.get("meta", m) for m in metas]
    seen = {(m.get("render_mode", "stock"), m.get("fast_version")) for m in inner}
    if len(seen) > 1:
        raise InvalidInput(f"the episodes were recorded in different render models {sorted(seen, key=str)}; "
                           "annotate and train on one recording")
    mode, version = seen.pop() if seen else ("stock", None)
    return {"mode": mode, "fast_version": version}


def native_bf16(device: str = "cpu") -> bool:
    """Whether bf16 autocast runs on real bf16 units: any CUDA device, or a CPU whose flags list
    avx512_bf16 or amx_bf16 (Linux's /proc/cpuinfo; elsewhere: no)."""
    if device != "cpu":
        return True
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return "avx512_bf16" in flags or "amx_bf16" in flags


@dataclass
class Source:
    """One annotated dataset of the training mixture, cached and labelled."""

    name: str
    frames: FrameCache
    labels: Labels
    batcher: Batcher | None
    train: np.ndarray  # frames that give action + text samples
    think_rows: np.ndarray  # rows of labels.think_frames that lie in training episodes
    weight: float


def _sources(annotations: list[Path], dataset: Path | None, cfg: TrainConfig):
    """(AnnotatedDataset, episodes that count, train episodes, held-out episodes) per annotation
    directory. The first is the demonstrations: it alone holds episodes out for the held-out check."""
    from seal.annotate.loader import AnnotatedDataset
    from seal.train.pipeline import split_episodes

    out = []
    for i, a in enumerate(annotations):
        ann = AnnotatedDataset(Path(a), Path(dataset) if dataset and i == 0 else None)
        annotated = ann.episodes
        dagger = any(ann.records[e].get("frame_labels") for e in annotated)
        # Imitation learns from demonstrations that reached the goal; failures recorded for the value
        # function (`seal demos record --keep-failures`) are left out. A DAgger episode's labels are the
        # teacher's, right or wrong as the rollout went, so every one of them counts.
        episodes = annotated if dagger else [e for e in annotated if _succeeded(ann.source.episode_meta(e))]
        if not episodes:
            raise InvalidInput(f"{a} has no successfully annotated episode of a successful demonstration "
                               f"({len(annotated)} annotated, none marked success)")
        if i == 0:
            tr, held = split_episodes(len(episodes), cfg.holdout, cfg.seed)
            tr, held = [episodes[j] for j in tr], [episodes[j] for j in held]
        else:
            tr, held = list(episodes), []
        out.append((ann, annotated, tr, held))
    return out


def train_vla(dataset: Path | None, annotations: Path | list[Path], out: Path, cfg: TrainConfig, model_cfg: VLAConfig,
              *, cache: Path | None = None, progress=None, command: str = "", mix: list[float] | None = None,
              init_from: str | None = None, plan_only_actions: bool | None = None) -> dict:
    """Train (or resume) a VLA into run directory ``out``; returns the summary (also summary.json).

    ``annotations``: one annotation directory or several (demonstrations first, then DAgger rounds);
    ``mix``: the share of each batch drawn from each (default: in proportion to their frames).
    ``init_from``: a VLA checkpoint to fine-tune (its network shape, tokenizer and normalization;
    ``model_cfg`` is then ignored).
    ``plan_only_actions``: whether the action expert reads the instruction (`VLAConfig.actions_read_instruction`
    negated); None keeps ``model_cfg``'s or the initial model's.
    ``progress(stage, done, total, metrics)``: stage "cache" (episodes decoded) or "train"."""
    out = Path(out)
    say = progress or (lambda *a, **k: None)
    torch.set_num_threads(cfg.threads)
    if cfg.bf16 is None:  # resolved before anything is saved or compared: a resume on this machine agrees
        cfg = replace(cfg, bf16=native_bf16(cfg.device))
    annotations = [Path(annotations)] if isinstance(annotations, (str, Path)) else [Path(a) for a in annotations]
    if not annotations:
        raise InvalidInput("seal train vla needs at least one --annotations directory")
    if mix is not None and (len(mix) != len(annotations) or any(not w >= 0 for w in mix) or sum(mix) <= 0):
        raise InvalidInput(f"--mix needs one weight >= 0 per --annotations directory ({len(annotations)}), not all "
                           f"zero; got {mix}")
    sources = _sources(annotations, dataset, cfg)
    ann, annotated, train_eps, held_eps = sources[0]
    episodes = train_eps + held_eps
    # one render model across every source (and the model fine-tuned): checked before any work
    render = recorded_render([a.source.episode_meta(e) for a, annotated_i, _, _ in sources for e in annotated_i])
    init = None
    if init_from:
        from seal.policies.vla.locate import resolve_checkpoint, trained_render

        was = trained_render(init_from)
        if was["recorded"] and (was["mode"], was["fast_version"]) != (render["mode"], render["fast_version"]):
            raise InvalidInput(f"--init-from {init_from} learned from {was['mode']!r} pixels (fast version "
                               f"{was['fast_version']}), the data is {render['mode']!r} (fast version "
                               f"{render['fast_version']}); fine-tune on data of the model's own render")
        init = load_checkpoint(resolve_checkpoint(init_from))
        model_cfg = init[0].cfg
    if plan_only_actions is not None:  # a training choice, not a shape: no weight changes with it
        model_cfg = replace(model_cfg, actions_read_instruction=not plan_only_actions)
    if not model_cfg.actions_read_instruction and cfg.instruction_dropout:
        raise InvalidInput("--instruction-dropout is for models whose actions read the instruction; with "
                           "--plan-only-actions they never do (the reasoning text keeps it: --text-share)")
    out.mkdir(parents=True, exist_ok=True)  # not before: annotations that cannot be used leave no empty run directory

    # tokenizer: trained once per run on the project's text and this data's labels (or the initial model's)
    tok_path = out / TOKENIZER
    if tok_path.is_file():
        tok = VLATokenizer.load(tok_path)
    elif init is not None:
        tok = init[1]
        tok_path.write_text(tok.to_json())
    else:
        tok = train_tokenizer(project_texts() + corpus_from_annotations(ann.records), model_cfg.vocab_size)
        tok_path.write_text(tok.to_json())
    model_cfg = replace(model_cfg, vocab_size=tok.vocab_size)

    built: list[Source] = []
    for i, (a, _, tr, held) in enumerate(sources):
        where = Path(cache) if cache else out / "cache"
        where = where if len(sources) == 1 else where / f"s{i}"
        fc = build_cache(a.source, tr + held, where, model_cfg.image_size, progress=lambda k, n: say("cache", k, n))
        lab = make_labels(fc, a.records, a.root)
        n_tr = int(sum(fc.lengths[: len(tr)]))
        usable = np.ones(len(fc.states), bool) if lab.usable is None else lab.usable
        built.append(Source(str(a.root), fc, lab, Batcher(fc, lab, tok, model_cfg),
                            np.flatnonzero(usable[:n_tr]), np.flatnonzero(lab.think_frames < n_tr),
                            float(mix[i]) if mix else float(n_tr)))
    frames, labels, batcher = built[0].frames, built[0].labels, built[0].batcher
    n_train = int(sum(frames.lengths[: len(train_eps)]))
    fingerprint = _fingerprint_all(built, model_cfg)

    with torch.random.fork_rng(devices=[]):  # seeded initial weights without touching the caller's RNG
        torch.manual_seed(cfg.seed)
        model = VLAModel(model_cfg).to(cfg.device)
    decay = [p for n, p in model.named_parameters() if p.ndim >= 2 and n != "pos" and not n.endswith(".pos")]
    rest = [p for n, p in model.named_parameters() if not (p.ndim >= 2 and n != "pos" and not n.endswith(".pos"))]
    opt = torch.optim.AdamW([{"params": decay, "weight_decay": cfg.weight_decay}, {"params": rest, "weight_decay": 0.0}],
                            lr=cfg.lr, betas=(0.9, 0.95))
    state = RunState(0, np.random.default_rng(cfg.seed), torch.Generator().manual_seed(cfg.seed))
    resume = _resume_dir(out)
    if resume is not None:
        _restore(resume, model, opt, state, cfg, model_cfg, fingerprint)
        _truncate_metrics(out / METRICS, state.step)
    else:
        if init is not None:  # its weights and normalization: the fine-tune starts where it ended
            model.load_state_dict(init[0].state_dict())
        else:
            s, a = frames.states[:n_train], frames.actions[:n_train]
            model.set_normalization(s.mean(0), s.std(0), a.mean(0), a.std(0))
        (out / METRICS).unlink(missing_ok=True)
    manifest = {"command": command, "dataset": str(Path(ann.source.root).resolve()),
                "render": render,
                "annotations": str(Path(annotations[0]).resolve()), "train_episodes": len(train_eps),
                "failed_demos_left_out": len(annotated) - len(episodes),
                "heldout_episodes": held_eps, "train_frames": n_train, "code_version": _code_version(),
                "train_config": asdict(cfg)}
    if len(built) > 1 or init is not None:
        total = sum(b.weight for b in built)
        manifest["sources"] = [{"annotations": str(Path(b.name).resolve()), "episodes": len(b.frames.episodes),
                                "frames": int(len(b.frames.states)), "usable_frames": int(len(b.train)),
                                "think_samples": int(len(b.think_rows)), "share": round(b.weight / total, 4)}
                               for b in built]
        manifest["init_from"] = str(init_from) if init_from else None
    held = _heldout_starts(frames, len(train_eps), cfg.eval_samples)
    last_eval: dict = {}
    last: dict = {}
    say("train", state.step, cfg.steps, None)
    t_save = time.monotonic()
    t0, s0 = time.perf_counter(), state.step
    model.train()
    stop = _DeferredStop()  # Ctrl-C / SIGTERM take effect between updates, never inside one
    try:
        with stop, open(out / METRICS, "a") as log:
            while state.step < cfg.steps:
                stop.check()
                batch = _draw_mixture(built, cfg, model_cfg, state)
                for group in opt.param_groups:
                    group["lr"] = learning_rate(cfg, state.step)
                with torch.autocast("cpu" if cfg.device == "cpu" else "cuda", dtype=torch.bfloat16, enabled=cfg.bf16):
                    loss, metrics = model.loss(batch, state.gen)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
                opt.step()
                state.step += 1
                last = {k: round(float(v), 6) for k, v in metrics.items()}
                rate = (state.step - s0) * cfg.batch_size / (time.perf_counter() - t0)
                last |= {"step": state.step, "samples_per_s": round(rate, 2)}
                if state.step % cfg.log_every == 0 or state.step == cfg.steps:
                    log.write(json.dumps(last) + "\n")
                    log.flush()
                if held and (state.step % cfg.eval_every == 0 or state.step == cfg.steps):
                    last_eval = evaluate(model, tok, batcher, held, device=cfg.device) | {"step": state.step,
                                                                                         "eval": True}
                    log.write(json.dumps(last_eval) + "\n")
                    log.flush()
                    model.train()
                if time.monotonic() - t_save > 60 * cfg.save_minutes or state.step == cfg.steps:
                    save_run(out, model, tok, opt, state, cfg, fingerprint, manifest | {"heldout": last_eval})
                    plot_curves(out / METRICS, out / CURVES)
                    t_save = time.monotonic()
                say("train", state.step, cfg.steps, last)
    except KeyboardInterrupt:
        save_run(out, model, tok, opt, state, cfg, fingerprint, manifest | {"heldout": last_eval})
        plot_curves(out / METRICS, out / CURVES)
        raise
    summary = {"run": str(out), "step": state.step, "params": count_parameters(model), "last": last,
               "heldout": last_eval, "train_episodes": train_eps, "heldout_episodes": held_eps,
               "config": asdict(cfg), "model": model_cfg.to_dict()}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


class _DeferredStop:
    """Holds SIGINT/SIGTERM until the current update is complete, so the checkpoint written on
    the way out is a consistent state (weights, optimizer, generators and step of one moment)."""

    def __init__(self):
        self.requested = False
        self._old: dict = {}

    def __enter__(self):
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._request)
        return self

    def _request(self, signum, frame) -> None:
        self.requested = True

    def check(self) -> None:
        if self.requested:
            raise KeyboardInterrupt

    def __exit__(self, *exc) -> None:
        import signal

        for sig, handler in self._old.items():
            signal.signal(sig, handler)


def corpus_from_annotations(records: dict[int, dict]) -> list[str]:
    """Instructions and every distinct reasoning label of the annotated episodes."""
    from seal.annotate.align import label_at

    out: list[str] = []
    for record in records.values():
        if record.get("status") != "ok":
            continue
        plans = list(record["plans"])
        frames = [int(m["dataset_frame"]) for m in record["critical_moments"]]
        out.append(record["instruction"])
        out += [label_at(plans, frames, t).text() for t in sorted({0, *(f for f in frames if f >= 0)})]
    return out


def _draw(batcher: Batcher, labels: Labels, train_frames, think_rows, cfg: TrainConfig, model_cfg: VLAConfig,
          state: RunState) -> dict:
    n_think = int(round(cfg.batch_size * cfg.think_fraction)) if model_cfg.reasoning and len(think_rows) else 0
    frames = state.rng.choice(train_frames, cfg.batch_size - n_think)
    reason = labels.reason[frames]
    if n_think:
        pick = state.rng.choice(think_rows, n_think)
        frames = np.concatenate([frames, labels.think_frames[pick]])
        reason = np.concatenate([reason, labels.think_reason[pick]])
    think = np.arange(len(frames)) >= cfg.batch_size - n_think
    if model_cfg.reasoning and not model_cfg.actions_read_instruction:
        # each ordinary sample trains either the text (as `reason` runs: with the instruction) or the chunk and
        # think flag (as `act` runs: without it); one prefix per sample keeps the step cost of the usual recipe
        text = (state.rng.random(len(frames)) < cfg.text_share) & ~think
        return batcher.batch(frames, reason, think, cfg.shift, state.gen, cfg.device, text=text)
    drop = None
    if cfg.instruction_dropout and model_cfg.reasoning:  # ordinary samples only: they carry a sub-plan
        drop = (state.rng.random(len(frames)) < cfg.instruction_dropout) & ~think
    return batcher.batch(frames, reason, think, cfg.shift, state.gen, cfg.device, drop=drop)


def _draw_mixture(sources: list[Source], cfg: TrainConfig, model_cfg: VLAConfig, state: RunState) -> dict:
    """One batch: each sample's source drawn by weight, then `_draw` within each source."""
    if len(sources) == 1:
        s = sources[0]
        return _draw(s.batcher, s.labels, s.train, s.think_rows, cfg, model_cfg, state)
    w = np.asarray([s.weight for s in sources])
    counts = state.rng.multinomial(cfg.batch_size, w / w.sum())
    parts = [_draw(s.batcher, s.labels, s.train, s.think_rows, replace(cfg, batch_size=int(c)), model_cfg, state)
             for s, c in zip(sources, counts) if c]
    return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}


def _restore(where: Path, model, opt, state: RunState, cfg: TrainConfig, model_cfg: VLAConfig, fingerprint: str):
    from safetensors.torch import load_file

    meta = json.loads((where / STATE_JSON).read_text())
    saved = {k: v for k, v in {**asdict(TrainConfig()), **meta["config"]}.items() if k not in _RESUMABLE}  # fields added since: defaults
    mine = {k: v for k, v in asdict(cfg).items() if k not in _RESUMABLE}
    loaded, _, _ = load_checkpoint(where)
    if saved != mine or meta["data"] != fingerprint or loaded.cfg != model_cfg:
        raise InvalidInput(f"{where.parent} was trained with other settings or data (saved {saved}, model "
                           f"{loaded.cfg.to_dict()}, data {meta['data']}; now {mine}, model {model_cfg.to_dict()}, "
                           f"data {fingerprint}); use another --out directory")
    model.load_state_dict(loaded.state_dict())
    tensors = load_file(str(where / STATE_TENSORS))
    _load_optimizer(opt, tensors, meta)
    state.gen.set_state(tensors["torch_generator"])
    state.rng.bit_generator.state = meta["numpy_rng"]
    state.step = int(meta["step"])


def _truncate_metrics(path: Path, step: int) -> None:
    """Drop lines logged after the checkpoint being resumed (they will be logged again)."""
    if not path.is_file():
        return
    keep = []
    for line in path.read_text().splitlines():
        try:
            if json.loads(line).get("step", 0) <= step:
                keep.append(line)
        except json.JSONDecodeError:
            break  # a torn last line
    path.write_text("".join(line + "\n" for line in keep))


def _fingerprint(frames: FrameCache, labels: Labels, model_cfg: VLAConfig) -> str:
    h = hashlib.sha1(json.dumps(frames.info, sort_keys=True).encode())
    h.update(np.ascontiguousarray(frames.actions).tobytes())
    h.update(labels.reason.tobytes())
    h.update("\n".join(labels.texts).encode())
    return h.hexdigest()[:12]


def _fingerprint_all(sources: list[Source], model_cfg: VLAConfig) -> str:
    """The data a run trains on; one source keeps the single-dataset fingerprint of earlier runs."""
    one = [_fingerprint(s.frames, s.labels, model_cfg) for s in sources]
    if len(sources) == 1:
        return one[0]
    return hashlib.sha1(json.dumps([one, [s.weight for s in sources]]).encode()).hexdigest()[:12]


def _heldout_starts(frames: FrameCache, n_train_eps: int, limit: int) -> list[int]:
    starts = [int(s) + t for s, n in zip(frames.starts[n_train_eps:], frames.lengths[n_train_eps:])
              for t in range(0, int(n), ACTION_HORIZON)]
    if len(starts) > limit:
        starts = [starts[i] for i in np.linspace(0, len(starts) - 1, limit).round().astype(int)]
    return starts


@torch.no_grad()
def evaluate(model: VLAModel, tok: VLATokenizer, batcher: Batcher, frames: list[int], *, device: str = "cpu",
             seed: int = 0) -> dict:
    """Held-out figures at chunk starts ``frames``: action MSE of one sampled chunk (fixed noise)
    against the recorded chunk on its valid steps, in the env's action units, and the share of
    greedy-decoded reasoning texts whose "Now I need to do" matches the label."""
    from seal.policies.base import parse_lenient, parse_reasoning
    from seal.policies.vla.policy import VLAPolicy
    from seal.sim.observation import Observation

    model.eval()
    policy = VLAPolicy(model, tok)
    labels, cache = batcher.labels, batcher.cache
    gen = torch.Generator().manual_seed(seed)
    sq, n_valid, match = 0.0, 0, 0
    for f in frames:
        instruction = labels.instructions[labels.instruction[f]]
        obs = Observation(state=cache.states[f], prompt=instruction, agent=np.asarray(cache.agent[f]),
                          wrist=np.asarray(cache.wrist[f]))
        text = labels.texts[labels.reason[f]]
        if model.cfg.reasoning:
            now = parse_lenient(policy.decode(policy.encode([obs])), instruction).now
            match += now == labels.now[labels.reason[f]]
            cond = policy.condition([obs], parse_reasoning(text))
        else:
            cond = policy.condition([obs], None)
        noise = torch.randn(1, PREDICT_HORIZON, ACTION_DIM, generator=gen).to(device)
        pred = model.sample_actions(cond, noise).clamp(-1, 1)[0].cpu().numpy()
        b = batcher.batch(np.asarray([f]), labels.reason[[f]], np.zeros(1, bool))
        valid = b["action_valid"][0].numpy()
        sq += float(((pred - b["actions"][0].numpy()) ** 2)[valid].sum())
        n_valid += int(valid.sum()) * ACTION_DIM
    out = {"action_mse": round(sq / max(n_valid, 1), 6), "eval_chunks": len(frames)}
    if model.cfg.reasoning:
        out["subplan_accuracy"] = round(match / max(len(frames), 1), 4)
    return out


def plot_curves(metrics: Path, png: Path) -> None:
    """Training losses and held-out figures against the step (matplotlib, no display)."""
    if not metrics.is_file():
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [json.loads(line) for line in metrics.read_text().splitlines() if line.strip()]
    train = [r for r in rows if not r.get("eval")]
    held = [r for r in rows if r.get("eval")]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for key in ("loss", "action", "text", "think"):
        pts = [(r["step"], r[key]) for r in train if key in r]
        if pts:
            axes[0].plot(*zip(*pts), label=key)
    axes[0].set_yscale("log")
    axes[0].set_xlabel("step")
    axes[0].set_title("training losses")
    axes[0].legend()
    for key in ("action_mse", "subplan_accuracy"):
        pts = [(r["step"], r[key]) for r in held if key in r]
        if pts:
            axes[1].plot(*zip(*pts), marker="o", label=key)
    axes[1].set_xlabel("step")
    axes[1].set_title("held-out episodes")
    if held:
        axes[1].legend()
    fig.tight_layout()
    tmp = png.with_name(png.stem + ".tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, png)


def heldout_eval(model: VLAModel, tok: VLATokenizer, annotations: Path, *, dataset: Path | None = None,
                 episodes: list[int] | None = None, holdout: float = 0.1, seed: int = 0, cache: Path | None = None,
                 samples: int = 64, device: str = "cpu") -> dict:
    """`evaluate` on held-out episodes of an annotated dataset: ``episodes`` (e.g. a checkpoint
    manifest's ``heldout_episodes``), else the trainer's seeded split at ``holdout``."""
    import tempfile

    from seal.annotate.loader import AnnotatedDataset
    from seal.train.pipeline import split_episodes

    ann = AnnotatedDataset(Path(annotations), Path(dataset) if dataset else None)
    if episodes is None:
        _, held = split_episodes(len(ann.episodes), holdout, seed)
        episodes = [ann.episodes[i] for i in held]
    missing = sorted(set(episodes) - set(ann.episodes))
    if missing:
        raise InvalidInput(f"held-out episode(s) {missing[:5]} are not annotated in {annotations}")
    with tempfile.TemporaryDirectory() as tmp:
        frames = build_cache(ann.source, list(episodes), Path(cache) if cache else Path(tmp) / "cache",
                             model.cfg.image_size)
        batcher = Batcher(frames, make_labels(frames, ann.records), tok, model.cfg)
        out = evaluate(model, tok, batcher, _heldout_starts(frames, 0, samples), device=device)
    return out | {"heldout_episodes": list(episodes)}
