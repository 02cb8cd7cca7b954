"""Annotate a LeRobot dataset: resumable, concurrent, safe to interrupt.

Output is a sidecar directory next to (not inside) the source dataset, which is never modified:

    OUT/annotate_info.json   source dataset (absolute path), backend, model, camera, horizon, tokenizer
    OUT/annotations.jsonl    one line per finished episode, ok or failed: THE commit record
    OUT/calls.jsonl          one line per model call: tokens, cost, latency, outcome
    OUT/data/chunk-000/episode_000000.parquet   per-frame labels of each annotated episode
    OUT/videos/episode_000000.mp4               the 10 fps clip the model watched (when made)

An episode's parquet (and clip) is written first, through a temp file and a rename; its
annotations.jsonl line is appended and fsynced last. A re-run trusts annotations.jsonl alone:
episodes with an ``ok`` line are skipped, a torn last line (crash mid-append) is dropped, and
files of uncommitted episodes are simply written again. Failed episodes keep their line (with
every raw reply) and are retried only with ``retry_failed=True``, which first removes their old
lines so that each episode has at most one line. One run at a time holds ``OUT/.lock``.
"""

from __future__ import annotations

import asyncio
import fcntl
import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from seal.annotate.align import (
    TOKEN_BUDGET,
    Cl100kCounter,
    TokenCounter,
    budget_summary,
    chunk_labels,
    training_sequences,
)
from seal.annotate.base import Annotator, AnnotatorResult, EpisodeInput
from seal.annotate.video import (
    VIDEO_FPS,
    FrameMap,
    camera_key,
    episode_instruction,
    episode_length,
    load_frames,
    resample,
    write_clip,
)
from seal.datasets.lerobot import LeRobotReader, read_jsonl, write_jsonl_atomic, open_dataset
from seal.errors import InvalidInput
from seal.policies.base import ACTION_HORIZON

INFO = "annotate_info.json"
ANNOTATIONS = "annotations.jsonl"
CALLS = "calls.jsonl"
LABELS_PATH = "data/chunk-{chunk:03d}/episode_{episode:06d}.parquet"
CLIP_PATH = "videos/episode_{episode:06d}.mp4"
CHUNK_SIZE = 1000
FORMAT = 1


@dataclass
class RunOptions:
    episodes: Sequence[int] | None = None  # None: all
    camera: str | None = None  # None: the agent view (see video.camera_key)
    horizon: int = ACTION_HORIZON
    token_budget: int = TOKEN_BUDGET
    concurrency: int = 4  # episodes in flight at once
    videos: bool | None = None  # write the 10 fps clips; None: when the annotator needs them
    retry_failed: bool = False


@dataclass
class RunSummary:
    selected: int = 0
    skipped: int = 0  # already annotated by an earlier run
    annotated: int = 0
    failed: int = 0
    wall_s: float = 0.0
    input_tokens: int = 0
    output_tokens: int = 0
    cost_usd: float = 0.0
    max_tokens: int = 0
    over_budget: int = 0  # training sequences longer than the token budget
    errors: list[str] = field(default_factory=list)


def parse_episode_list(text: str, n: int) -> list[int]:
    """'0,3,5-9' -> [0, 3, 5, 6, 7, 8, 9], each checked against 0..n-1."""
    out: list[int] = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        try:
            if "-" in part:
                lo, hi = (int(x) for x in part.split("-", 1))
                if hi < lo:
                    raise ValueError
                out += range(lo, hi + 1)
            else:
                out.append(int(part))
        except ValueError:
            raise InvalidInput(f"bad episode selection {part!r}; use indices and ranges like 0,3,5-9") from None
    bad = [e for e in out if not 0 <= e < n]
    if bad:
        raise InvalidInput(f"episode(s) {bad[:5]} out of range; the dataset has episodes 0..{n - 1}")
    return sorted(set(out))


def read_annotations(out: Path) -> dict[int, dict]:
    """The committed record of each episode (the last line wins; a torn last line is ignored)."""
    records, _ = read_jsonl(Path(out) / ANNOTATIONS)
    return {int(r["episode_index"]): r for r in records}


class _OutDir:
    """The sidecar directory: lock, compatibility check, commits."""

    def __init__(self, out: Path, info: dict):
        self.root = Path(out)
        if self.root.exists() and not self.root.is_dir():
            raise InvalidInput(f"--out {self.root} exists and is not a directory")
        self.root.mkdir(parents=True, exist_ok=True)
        self._lock = open(self.root / ".lock", "w")  # noqa: SIM115 - held open for the run: the flock lives on it
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._lock.close()
            raise InvalidInput(f"{self.root} is being written by another `seal annotate` run") from None
        try:
            self._check_or_write_info(info)
            records, torn = read_jsonl(self.root / ANNOTATIONS)
            if torn:  # a crash mid-append: that episode simply runs again
                write_jsonl_atomic(self.root / ANNOTATIONS, records)
            self.records = records
        except BaseException:
            self.close()
            raise

    def _check_or_write_info(self, info: dict) -> None:
        path = self.root / INFO
        if path.exists():
            old = json.loads(path.read_text())
            keys = ("source", "backend", "model", "camera", "horizon", "video_fps")
            diff = [f"{k}: {old.get(k)!r} there, {info[k]!r} now" for k in keys if old.get(k) != info[k]]
            if diff:
                raise InvalidInput(f"{self.root} holds annotations of another run ({'; '.join(diff)}); "
                                   f"use a new --out directory")
            return
        if any(p.name != ".lock" for p in self.root.iterdir()):
            raise InvalidInput(f"--out {self.root} is not empty and holds no {INFO}; give a new or empty directory")
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(info, indent=2) + "\n")
        os.replace(tmp, path)

    def drop_failed(self, episodes: set[int]) -> None:
        kept = [r for r in self.records if not (r["status"] != "ok" and r["episode_index"] in episodes)]
        if len(kept) != len(self.records):
            write_jsonl_atomic(self.root / ANNOTATIONS, kept)
            self.records = kept

    def commit(self, record: dict, labels: pa.Table | None, calls: list[dict]) -> None:
        if labels is not None:
            path = self.root / record["labels_path"]
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(path.name + ".tmp")
            pq.write_table(labels, tmp)
            os.replace(tmp, path)
        if calls:  # the call log is informative; it is not what resume trusts
            with open(self.root / CALLS, "a") as f:
                f.write("".join(json.dumps(c) + "\n" for c in calls))
        with open(self.root / ANNOTATIONS, "a") as f:
            f.write(json.dumps(record) + "\n")
            f.flush()
            os.fsync(f.fileno())  # the commit point
        self.records.append(record)

    def close(self) -> None:
        if not self._lock.closed:
            self._lock.close()


def _labels_table(episode: int, instruction: str, length: int, plans: list[str], frames: list[int],
                  horizon: int, counter: TokenCounter, global_index: np.ndarray | None, budget: int):
    """Per-frame label rows (each frame carries the label of the chunk it belongs to)."""
    labels = chunk_labels(plans, frames, length, horizon)
    sequences = training_sequences(instruction, labels, length, counter)
    chunk_of = np.arange(length) // horizon
    pick = lambda values: [values[c] for c in chunk_of]
    frame_index = np.arange(length, dtype=np.int64)
    table = pa.table({
        "episode_index": pa.array(np.full(length, episode, dtype=np.int64)),
        "frame_index": pa.array(frame_index),
        "index": pa.array(global_index if global_index is not None else frame_index),
        "chunk_start": pa.array((chunk_of * horizon).astype(np.int64)),
        "is_chunk_start": pa.array(frame_index % horizon == 0),
        "reasoning": pa.array(pick([lb.text for lb in labels])).dictionary_encode(),
        "now": pa.array(pick([lb.reasoning.now for lb in labels])).dictionary_encode(),
        "done_count": pa.array(pick([len(lb.reasoning.done) for lb in labels]), pa.int32()),
        "new_subplan": pa.array(pick([lb.new_subplan for lb in labels]), pa.bool_()),
        "sequence": pa.array(pick([s.text for s in sequences])).dictionary_encode(),
        "n_tokens": pa.array(pick([s.n_tokens for s in sequences]), pa.int32()),
        "action_from": pa.array(pick([s.action_from for s in sequences]), pa.int64()),
        "action_to": pa.array(pick([s.action_to for s in sequences]), pa.int64()),
    })
    return table, budget_summary(sequences, budget)


def annotate_dataset(dataset: Path | LeRobotReader, out: Path, annotator: Annotator, options: RunOptions | None = None,
                     *, counter: TokenCounter | None = None, progress: Callable[[dict, RunSummary], None] | None = None,
                     on_start: Callable[[int, int], None] | None = None) -> RunSummary:
    """Annotate the selected episodes of ``dataset`` into the sidecar ``out`` (see module doc).

    ``on_start(todo, skipped)`` is called once the work is known; ``progress(record, summary)``
    after each committed episode.
    """
    options = options or RunOptions()
    if options.concurrency < 1:
        raise InvalidInput(f"concurrency must be >= 1, got {options.concurrency}")
    if options.horizon < 1:
        raise InvalidInput(f"horizon must be >= 1, got {options.horizon}")
    reader = dataset if isinstance(dataset, LeRobotReader) else open_dataset(Path(dataset))
    camera = camera_key(reader, options.camera)
    selected = list(range(reader.num_episodes)) if options.episodes is None else list(options.episodes)
    for e in selected:
        reader.episode_meta(e)  # raises a clear error for an out-of-range index
    counter = counter or Cl100kCounter()
    videos = annotator.needs_clip if options.videos is None else options.videos
    if annotator.backend == "gemini" and not videos:
        raise InvalidInput("the gemini backend uploads the clip: it cannot run with videos off")
    info = {"format": FORMAT, "source": str(Path(reader.root).resolve()), "source_version": reader.version,
            "dataset_fps": reader.fps, "video_fps": VIDEO_FPS, "camera": camera, "backend": annotator.backend,
            "model": annotator.model, "horizon": options.horizon, "token_budget": options.token_budget,
            "tokenizer": counter.name}
    store = _OutDir(Path(out), info)
    summary = RunSummary(selected=len(selected))
    started = time.perf_counter()
    try:
        done = {r["episode_index"] for r in store.records if r["status"] == "ok"}
        failed = {r["episode_index"] for r in store.records if r["status"] != "ok"}
        todo = [e for e in selected if e not in done and (options.retry_failed or e not in failed)]
        if options.retry_failed:
            store.drop_failed(set(todo))
        summary.skipped = len(selected) - len(todo)
        if on_start:
            on_start(len(todo), summary.skipped)
        asyncio.run(_run(reader, store, annotator, todo, camera, videos, options, counter, summary, progress))
    finally:
        store.close()
        summary.wall_s = round(time.perf_counter() - started, 3)
    return summary


def _prepare(reader: LeRobotReader, store: _OutDir, episode: int, camera: str, videos: bool,
             need_clip: bool) -> tuple[EpisodeInput, np.ndarray | None]:
    """Read one episode and make its clip (CPU work: runs in a worker thread)."""
    meta = reader.episode_meta(episode)
    length = episode_length(reader, episode)
    frame_map = FrameMap(dataset_fps=reader.fps, length=length)
    job = EpisodeInput(episode=episode, instruction=episode_instruction(reader, episode), frame_map=frame_map,
                       truth_plans=list(meta.get("subplans") or []) or None,
                       truth_frames=[int(f) for f in meta.get("critical_frames") or []] or None)
    if need_clip or videos:
        frames = load_frames(reader, episode, camera)
        if len(frames) != length:
            raise InvalidInput(f"episode {episode}: camera {camera!r} has {len(frames)} frames but the episode "
                               f"has {length}; the dataset is corrupt")
        job.clip = resample(frames, frame_map)
        if videos:
            job.clip_path = write_clip(job.clip, store.root / CLIP_PATH.format(episode=episode), frame_map.video_fps)
    try:
        global_index = reader.frames(episode).column("index").to_numpy()
    except KeyError:
        global_index = None
    return job, global_index


async def _run(reader, store, annotator, todo, camera, videos, options, counter, summary, progress) -> None:
    semaphore = asyncio.Semaphore(options.concurrency)

    async def one(episode: int) -> None:
        async with semaphore:
            t0 = time.perf_counter()
            try:
                job, global_index = await asyncio.to_thread(_prepare, reader, store, episode, camera, videos,
                                                            annotator.needs_clip)
            except InvalidInput as exc:  # a damaged episode fails alone; the run goes on
                result = AnnotatorResult(status="failed", error=f"reading the episode failed: {exc}")
                record = {"episode_index": episode, "status": "failed", "backend": annotator.backend,
                          "model": annotator.model, "plans": [], "critical_moments": [], "error": result.error,
                          "raw": [], "calls": 0, "cost_usd": 0.0}
                labels = None
            else:
                result = await annotator.annotate(job)
                record, labels = _record(job, result, annotator, options, counter, global_index, videos)
            record["wall_s"] = round(time.perf_counter() - t0, 3)
            store.commit(record, labels, result.calls)
            _tally(summary, record, result)
            if progress:
                progress(record, summary)

    tasks = [asyncio.create_task(one(e)) for e in todo]
    try:
        # The first error (a rejected key, a corrupt episode) stops the run; finished episodes stay.
        await asyncio.gather(*tasks)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await annotator.aclose()


def _record(job: EpisodeInput, result: AnnotatorResult, annotator: Annotator, options: RunOptions,
            counter: TokenCounter, global_index, videos: bool) -> tuple[dict, pa.Table | None]:
    record = {
        "episode_index": job.episode, "status": result.status, "backend": annotator.backend,
        "model": annotator.model, "instruction": job.instruction, "length": job.frame_map.length,
        "plans": [], "critical_moments": [], "error": result.error, "raw": result.raw,
        "calls": len(result.calls), "cached": result.cached, "input_tokens": result.input_tokens,
        "output_tokens": result.output_tokens, "cost_usd": round(result.cost_usd, 6),
        "frame_map": job.frame_map.to_dict(),
        "clip_path": CLIP_PATH.format(episode=job.episode) if videos else None,
    }
    labels = None
    if result.status == "ok" and result.annotation is not None:
        a = result.annotation
        labels, budget = _labels_table(job.episode, job.instruction, job.frame_map.length, a.plans,
                                       a.dataset_frames, options.horizon, counter, global_index, options.token_budget)
        record.update(plans=a.plans, critical_moments=a.moments(), tokens=budget,
                      labels_path=LABELS_PATH.format(chunk=job.episode // CHUNK_SIZE, episode=job.episode))
    return record, labels


def _tally(summary: RunSummary, record: dict, result: AnnotatorResult) -> None:
    if record["status"] == "ok":
        summary.annotated += 1
        summary.max_tokens = max(summary.max_tokens, record["tokens"]["max_tokens"])
        summary.over_budget += record["tokens"]["over_budget"]
    else:
        summary.failed += 1
        summary.errors.append(f"episode {record['episode_index']}: {record['error']}")
    summary.input_tokens += result.input_tokens
    summary.output_tokens += result.output_tokens
    summary.cost_usd = round(summary.cost_usd + result.cost_usd, 6)


def summary_dict(summary: RunSummary) -> dict:
    return asdict(summary)
