"""Write and read demonstrations as a LeRobot dataset (codebase_version "v2.1" layout).

Layout written (the one LeRobot <= 0.3 reads and writes, and that `convert_dataset_v21_to_v30`
upgrades):

    meta/info.json                 dataset description, rewritten atomically after each episode
    meta/episodes.jsonl            one line per complete episode: THE commit record
    meta/episodes_stats.jsonl      per-episode min/max/mean/std/count
    meta/tasks.jsonl               deduplicated language instructions
    data/chunk-000/episode_000000.parquet
    videos/chunk-000/observation.images.image/episode_000000.mp4        (agent view)
    videos/chunk-000/observation.images.wrist_image/episode_000000.mp4  (wrist view)

Crash safety: an episode's files are written first (each through a temp file + rename) and its
episodes.jsonl line last. A writer reopened on the directory trusts episodes.jsonl alone: it drops
a torn last line, then deletes the files and stats lines of any later episode index, and rebuilds
info.json from what remains. A crash therefore loses at most the episode being written.

The reader also understands the newer "v3.0" layout (many episodes per parquet/mp4 file, episode
metadata in parquet), so data recorded by current LeRobot can be read back the same way.
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import av
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from seal.errors import InvalidInput

CODEBASE_VERSION = "v2.1"
CHUNKS_SIZE = 1000  # episodes per chunk directory, LeRobot's default
DATA_PATH = "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"
VIDEO_PATH = "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"

AGENT_VIDEO_KEY = "observation.images.image"
WRIST_VIDEO_KEY = "observation.images.wrist_image"
VIDEO_KEYS = (AGENT_VIDEO_KEY, WRIST_VIDEO_KEY)
STATE_KEY = "observation.state"
ACTION_KEY = "action"

IMAGE_SHAPE = (224, 224, 3)
STATE_DIM = 8
ACTION_DIM = 7
STATE_NAMES = ["eef_pos_x", "eef_pos_y", "eef_pos_z",
               "eef_axis_angle_x", "eef_axis_angle_y", "eef_axis_angle_z",
               "gripper_qpos_0", "gripper_qpos_1"]
ACTION_NAMES = ["d_pos_x", "d_pos_y", "d_pos_z", "d_rot_x", "d_rot_y", "d_rot_z", "gripper"]

# H.264 rather than LeRobot's default AV1: every PyAV/ffmpeg build decodes it, and encoding is
# fast on 2 cores. A keyframe every 2 frames (LeRobot's choice) keeps random frame access cheap
# for training loaders; crf 20 is visually near-lossless for 224x224 renders.
VIDEO_CODEC = "libx264"
VIDEO_CODEC_NAME = "h264"  # what the stream reports; what LeRobot writes into info.json
PIX_FMT = "yuv420p"
CRF = 20
GOP = 2
# Below 224 px (a policy trained at 64 px) the frames are the training data itself, and 4:2:0
# chroma at 32x32 is far from what the policy sees at run time (up to 59 levels off on a 64-px
# render). There the video is lossless RGB H.264 (libx264rgb, crf 0): bit-exact, ~3 KB a frame.
LOSSLESS_BELOW = 224
LOSSLESS_CODEC, LOSSLESS_PIX_FMT = "libx264rgb", "rgb24"
STATS_MAX_IMAGE_SAMPLES = 100  # LeRobot estimates image stats from <= ~100 evenly spaced frames

_EPISODE_FILE = re.compile(r"episode_(\d{6})\.(parquet|mp4)$")


@dataclass
class Episode:
    """One recorded demonstration, T frames long."""

    instruction: str                 # the task's language instruction
    agent_images: np.ndarray         # (T, 224, 224, 3) uint8, agent view
    wrist_images: np.ndarray         # (T, 224, 224, 3) uint8, wrist view
    states: np.ndarray               # (T, 8) float32: eef pos(3), axis-angle(3), gripper qpos(2)
    actions: np.ndarray              # (T, 7) float32 in [-1, 1]
    subplans: list[str] = field(default_factory=list)         # ground-truth sub-plan texts, in order
    critical_frames: list[int] = field(default_factory=list)  # per sub-plan: frame where its sub-goal first held, -1 if never
    meta: dict = field(default_factory=dict)                   # JSON-able extras: suite, task_id, init_index, success, seed

    @property
    def length(self) -> int:
        return len(self.states)


def _features(fps: int, image_size: int = IMAGE_SHAPE[0]) -> dict[str, dict]:
    """The info.json `features` block; the same keys, dtypes and shapes LeRobot v2.1 writes."""
    shape = (image_size, image_size, 3)
    video_info = {"video.height": shape[0], "video.width": shape[1],
                  "video.codec": VIDEO_CODEC_NAME,
                  "video.pix_fmt": LOSSLESS_PIX_FMT if image_size < LOSSLESS_BELOW else PIX_FMT,
                  "video.is_depth_map": False,
                  "video.fps": fps, "video.channels": shape[2], "has_audio": False}
    video = {"dtype": "video", "shape": list(shape), "names": ["height", "width", "channels"],
             "info": video_info}
    scalar = {"shape": [1], "names": None}
    return {
        AGENT_VIDEO_KEY: video,
        WRIST_VIDEO_KEY: json.loads(json.dumps(video)),  # a copy, so json.dump writes no shared refs
        STATE_KEY: {"dtype": "float32", "shape": [STATE_DIM], "names": STATE_NAMES},
        ACTION_KEY: {"dtype": "float32", "shape": [ACTION_DIM], "names": ACTION_NAMES},
        "timestamp": {"dtype": "float32", **scalar},
        "frame_index": {"dtype": "int64", **scalar},
        "episode_index": {"dtype": "int64", **scalar},
        "index": {"dtype": "int64", **scalar},
        "task_index": {"dtype": "int64", **scalar},
    }


def _schema() -> pa.Schema:
    # Fixed-size lists are what HF `datasets` makes of LeRobot's Sequence(length=n) features; the
    # "huggingface" metadata lets `datasets.load_dataset("parquet")` restore those features as-is.
    seq = lambda n: {"feature": {"dtype": "float32", "_type": "Value"}, "length": n, "_type": "Sequence"}
    value = lambda dtype: {"dtype": dtype, "_type": "Value"}
    hf = {"info": {"features": {
        STATE_KEY: seq(STATE_DIM), ACTION_KEY: seq(ACTION_DIM), "timestamp": value("float32"),
        "frame_index": value("int64"), "episode_index": value("int64"), "index": value("int64"),
        "task_index": value("int64")}}}
    return pa.schema([
        pa.field(STATE_KEY, pa.list_(pa.float32(), STATE_DIM)),
        pa.field(ACTION_KEY, pa.list_(pa.float32(), ACTION_DIM)),
        pa.field("timestamp", pa.float32()),
        pa.field("frame_index", pa.int64()),
        pa.field("episode_index", pa.int64()),
        pa.field("index", pa.int64()),
        pa.field("task_index", pa.int64()),
    ], metadata={"huggingface": json.dumps(hf)})


# --------------------------------------------------------------------------------------------
# small file helpers


def _write_json_atomic(path: Path, obj: Any) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=4) + "\n")
    os.replace(tmp, path)


def read_jsonl(path: Path) -> tuple[list[dict], bool]:
    """Complete records of a jsonl file, and whether a torn (partial) last line was skipped.

    Only the last line can be torn (we only ever append); a bad line elsewhere is corruption.
    """
    if not path.exists():
        return [], False
    text = path.read_text()
    lines = text.split("\n")
    torn = False
    if lines and lines[-1] == "":
        lines.pop()
    elif lines:  # no trailing newline: the append of the last line did not finish
        lines.pop()
        torn = True
    records = []
    for n, line in enumerate(lines, 1):
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError as e:
            raise InvalidInput(f"{path}: line {n} is not valid JSON ({e}); the dataset is corrupt") from None
    return records, torn


def write_jsonl_atomic(path: Path, records: list[dict]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("".join(json.dumps(r) + "\n" for r in records))
    os.replace(tmp, path)


def _append_jsonl(path: Path, record: dict, *, sync: bool = False) -> None:
    with path.open("a") as f:
        f.write(json.dumps(record) + "\n")
        f.flush()
        if sync:
            os.fsync(f.fileno())


def _json_default(obj: Any) -> Any:
    # numpy scalars turn up in meta dicts all the time (np.bool_ success flags, np.int64 seeds)
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"{type(obj).__name__} is not JSON serializable")


def encode_video(frames: np.ndarray, path: Path, fps: int, *, lossless: bool = False) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with av.open(str(tmp), mode="w", format="mp4") as container:
        stream = container.add_stream(LOSSLESS_CODEC if lossless else VIDEO_CODEC, rate=fps)
        stream.height, stream.width = frames.shape[1:3]
        stream.pix_fmt = LOSSLESS_PIX_FMT if lossless else PIX_FMT
        stream.options = {"crf": "0" if lossless else str(CRF), "g": str(GOP)}
        for image in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")))
        container.mux(stream.encode())  # flush the encoder's delayed frames
    os.replace(tmp, path)


def _decode_video(path: Path, *, start_s: float | None = None, end_s: float | None = None) -> np.ndarray:
    """All frames of `path` as (N, H, W, 3) uint8, or only those with start_s <= pts < end_s."""
    if not path.exists():
        raise InvalidInput(f"video file {path} is missing; the dataset is incomplete")
    eps = 1e-4  # LeRobot's timestamp tolerance; frame times are multiples of 1/fps
    images = []
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        if start_s:
            # lands on the keyframe at or before start_s; earlier frames are skipped below
            container.seek(int(start_s / stream.time_base), stream=stream, backward=True)
        for frame in container.decode(stream):
            t = float(frame.pts * stream.time_base) if frame.pts is not None else None
            if start_s is not None and t is not None and t < start_s - eps:
                continue
            if end_s is not None and t is not None and t >= end_s - eps:
                break
            images.append(frame.to_ndarray(format="rgb24"))
    if not images:
        return np.zeros((0, 0, 0, 3), np.uint8)
    return np.stack(images)


def _stats(array: np.ndarray) -> dict[str, list]:
    # Same reductions as LeRobot's compute_episode_stats; 1-D columns keep a length-1 axis.
    keepdims = array.ndim == 1
    return {"min": np.min(array, axis=0, keepdims=keepdims).tolist(),
            "max": np.max(array, axis=0, keepdims=keepdims).tolist(),
            "mean": np.mean(array, axis=0, keepdims=keepdims).tolist(),
            "std": np.std(array, axis=0, keepdims=keepdims).tolist(),
            "count": [len(array)]}


def _image_stats(images: np.ndarray) -> dict[str, list]:
    # Per channel over sampled frames, scaled to [0, 1], shaped (3, 1, 1), as LeRobot stores them.
    n = min(len(images), STATS_MAX_IMAGE_SAMPLES)
    sample = images[np.round(np.linspace(0, len(images) - 1, n)).astype(int)].astype(np.float32) / 255.0
    reduce = lambda f: f(sample, axis=(0, 1, 2)).reshape(3, 1, 1).tolist()
    return {"min": reduce(np.min), "max": reduce(np.max), "mean": reduce(np.mean), "std": reduce(np.std),
            "count": [n]}


# --------------------------------------------------------------------------------------------
# validation


def _check_array(name: str, value: Any, shape: tuple, dtype: type, T: int | None) -> int:
    """Check one Episode array; return its length T. `shape` excludes the leading T axis."""
    expected = f"({'T' if T is None else T}, {', '.join(map(str, shape))}) {np.dtype(dtype).name}"
    if not isinstance(value, np.ndarray):
        raise InvalidInput(f"Episode.{name} must be a numpy array of shape {expected}, got {type(value).__name__}")
    if value.ndim != len(shape) + 1 or value.shape[1:] != shape:
        raise InvalidInput(f"Episode.{name} has shape {value.shape}; expected {expected}")
    if value.dtype != dtype:
        raise InvalidInput(f"Episode.{name} has dtype {value.dtype}; expected {expected} "
                           f"(convert with .astype(np.{np.dtype(dtype).name}) if the values are in range)")
    if T is not None and len(value) != T:
        raise InvalidInput(f"Episode.{name} has {len(value)} frames but Episode.states has {T}; "
                           f"all arrays must have the same length T")
    return len(value)


def validate_episode(episode: Episode, image_size: int = IMAGE_SHAPE[0]) -> None:
    """Raise InvalidInput naming the first problem that would make `episode` unwritable."""
    if not isinstance(episode, Episode):
        raise InvalidInput(f"expected a seal.datasets.Episode, got {type(episode).__name__}")
    if not isinstance(episode.instruction, str) or not episode.instruction.strip():
        raise InvalidInput(f"Episode.instruction must be a non-empty string, got {episode.instruction!r}")
    T = _check_array("states", episode.states, (STATE_DIM,), np.float32, None)
    if T == 0:
        raise InvalidInput("Episode.states is empty; an episode needs at least one frame")
    _check_array("actions", episode.actions, (ACTION_DIM,), np.float32, T)
    shape = (image_size, image_size, 3)
    _check_array("agent_images", episode.agent_images, shape, np.uint8, T)
    _check_array("wrist_images", episode.wrist_images, shape, np.uint8, T)
    if not np.isfinite(episode.states).all():
        raise InvalidInput("Episode.states contains NaN or Inf; only finite values can be stored")
    if not np.isfinite(episode.actions).all() or np.abs(episode.actions).max() > 1.0:
        raise InvalidInput(f"Episode.actions must be finite and in [-1, 1] (the env's action space), got "
                           f"range [{np.nanmin(episode.actions)}, {np.nanmax(episode.actions)}]; clip them first")
    if not all(isinstance(s, str) for s in episode.subplans):
        raise InvalidInput("Episode.subplans must be a list of strings")
    if len(episode.subplans) != len(episode.critical_frames):
        raise InvalidInput(f"Episode has {len(episode.subplans)} subplans but {len(episode.critical_frames)} "
                           f"critical_frames; there must be exactly one critical frame per sub-plan")
    for k, f in enumerate(episode.critical_frames):
        if isinstance(f, bool) or not isinstance(f, (int, np.integer)) or not -1 <= f < T:
            raise InvalidInput(f"Episode.critical_frames[{k}] is {f!r}; expected a frame index in "
                               f"[0, {T - 1}] or -1 (sub-goal never held)")
    if not isinstance(episode.meta, dict):
        raise InvalidInput(f"Episode.meta must be a dict, got {type(episode.meta).__name__}")
    try:
        json.dumps(episode.meta, default=_json_default)
    except (TypeError, ValueError) as e:
        raise InvalidInput(f"Episode.meta must be JSON-serializable: {e}") from None


# --------------------------------------------------------------------------------------------
# writer


class LeRobotWriter:
    """Appends episodes to a v2.1 LeRobot dataset at `root`, creating or resuming it.

    Each `add` leaves the dataset complete and readable. Only one writer may hold a dataset at a
    time (an advisory lock on meta/.writer.lock); `close()` or leaving a `with` block releases it.
    """

    def __init__(self, root: Path, *, fps: int = 20, robot_type: str = "panda",
                 image_size: int = IMAGE_SHAPE[0]) -> None:
        if isinstance(fps, bool) or not isinstance(fps, int) or fps <= 0:
            raise InvalidInput(f"fps must be a positive integer, got {fps!r}")
        if isinstance(image_size, bool) or not isinstance(image_size, int) or not 16 <= image_size <= 1024:
            raise InvalidInput(f"image_size must be an integer in 16..1024 (px per side), got {image_size!r}")
        self.image_size = image_size
        self.root = Path(root)
        self.fps = fps
        self.robot_type = robot_type
        if self.root.exists() and not self.root.is_dir():
            raise InvalidInput(f"{self.root} exists and is not a directory")
        info_path = self.root / "meta" / "info.json"
        lock_path = self.root / "meta" / ".writer.lock"
        # Our own lock file (left by a writer that died before writing info.json) does not count.
        if self.root.exists() and not info_path.exists() and any(
                p.is_file() and p != lock_path for p in self.root.rglob("*")):
            raise InvalidInput(f"{self.root} is not empty and is not a LeRobot dataset (no meta/info.json); "
                               f"give an empty or new directory, or an existing v2.1 dataset")
        (self.root / "meta").mkdir(parents=True, exist_ok=True)
        self._lock = open(lock_path, "w")
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._lock.close()
            raise InvalidInput(f"{self.root} is already open in another LeRobotWriter") from None
        try:
            if info_path.exists():
                self._check_compatible(json.loads(info_path.read_text()))
            self._episodes: list[dict] = []
            self._tasks: dict[str, int] = {}
            self._total_frames = 0
            self._recover()
        except BaseException:
            self.close()
            raise

    # -- opening

    def _check_compatible(self, info: dict) -> None:
        version = info.get("codebase_version")
        if version != CODEBASE_VERSION:
            raise InvalidInput(f"{self.root} is a LeRobot dataset of codebase_version {version!r}; "
                               f"this writer appends only to {CODEBASE_VERSION!r} datasets")
        differences = []
        if info.get("fps") != self.fps:
            differences.append(f"fps is {info.get('fps')!r} there, {self.fps!r} requested")
        if info.get("robot_type") != self.robot_type:
            differences.append(f"robot_type is {info.get('robot_type')!r} there, {self.robot_type!r} requested")
        expected = _features(self.fps, self.image_size)
        theirs = info.get("features", {})
        for key in sorted(set(expected) | set(theirs)):
            mine, other = expected.get(key), theirs.get(key)
            if mine is None or other is None:
                differences.append(f"feature {key!r} is {'missing' if other is None else 'extra'} there")
            elif (mine["dtype"], list(mine["shape"])) != (other.get("dtype"), list(other.get("shape", []))):
                differences.append(f"feature {key!r} is {other.get('dtype')} {other.get('shape')} there, "
                                   f"{mine['dtype']} {mine['shape']} here")
        if differences:
            raise InvalidInput(f"cannot append to {self.root}: " + "; ".join(differences))

    def _recover(self) -> None:
        """Load the committed episodes and remove every trace of an episode that was not committed."""
        meta = self.root / "meta"
        episodes, torn = read_jsonl(meta / "episodes.jsonl")
        for position, record in enumerate(episodes):
            if record.get("episode_index") != position:
                raise InvalidInput(f"{meta / 'episodes.jsonl'}: line {position + 1} has episode_index "
                                   f"{record.get('episode_index')!r}, expected {position}; the dataset is corrupt")
        if torn:
            write_jsonl_atomic(meta / "episodes.jsonl", episodes)
        n = len(episodes)

        tasks, torn = read_jsonl(meta / "tasks.jsonl")
        if torn:
            write_jsonl_atomic(meta / "tasks.jsonl", tasks)
        self._tasks = {t["task"]: t["task_index"] for t in tasks}

        stats, torn = read_jsonl(meta / "episodes_stats.jsonl")
        kept = [s for s in stats if s.get("episode_index", n) < n]
        if torn or len(kept) != len(stats):
            write_jsonl_atomic(meta / "episodes_stats.jsonl", kept)

        # Files of uncommitted episodes, and temp files of interrupted writes.
        for directory in (self.root / "data", self.root / "videos"):
            if not directory.exists():
                continue
            for path in directory.rglob("*"):
                if not path.is_file():
                    continue
                name = path.name.removesuffix(".tmp")
                match = _EPISODE_FILE.search(name)
                if match and (path.name.endswith(".tmp") or int(match.group(1)) >= n):
                    path.unlink()

        self._episodes = episodes
        self._total_frames = sum(int(e["length"]) for e in episodes)
        self._write_info()

    # -- writing

    @property
    def num_episodes(self) -> int:
        return len(self._episodes)

    def add(self, episode: Episode) -> int:
        """Write `episode` to disk now and return its episode_index."""
        if self._lock.closed:
            raise InvalidInput(f"this LeRobotWriter on {self.root} is closed")
        validate_episode(episode, self.image_size)
        index = len(self._episodes)
        chunk = index // CHUNKS_SIZE
        T = episode.length
        task_index = self._tasks.get(episode.instruction, len(self._tasks))

        lossless = self.image_size < LOSSLESS_BELOW
        encode_video(episode.agent_images, self.root / VIDEO_PATH.format(
            episode_chunk=chunk, video_key=AGENT_VIDEO_KEY, episode_index=index), self.fps, lossless=lossless)
        encode_video(episode.wrist_images, self.root / VIDEO_PATH.format(
            episode_chunk=chunk, video_key=WRIST_VIDEO_KEY, episode_index=index), self.fps, lossless=lossless)

        frame_index = np.arange(T, dtype=np.int64)
        columns = {
            "timestamp": (frame_index / self.fps).astype(np.float32),
            "frame_index": frame_index,
            "episode_index": np.full(T, index, dtype=np.int64),
            "index": np.arange(self._total_frames, self._total_frames + T, dtype=np.int64),
            "task_index": np.full(T, task_index, dtype=np.int64),
        }
        table = pa.Table.from_arrays([
            pa.FixedSizeListArray.from_arrays(pa.array(episode.states.reshape(-1)), STATE_DIM),
            pa.FixedSizeListArray.from_arrays(pa.array(episode.actions.reshape(-1)), ACTION_DIM),
            *(pa.array(columns[k]) for k in ("timestamp", "frame_index", "episode_index", "index", "task_index")),
        ], schema=_schema())
        data_path = self.root / DATA_PATH.format(episode_chunk=chunk, episode_index=index)
        data_path.parent.mkdir(parents=True, exist_ok=True)
        tmp = data_path.with_name(data_path.name + ".tmp")
        pq.write_table(table, tmp)
        os.replace(tmp, data_path)

        meta = self.root / "meta"
        if episode.instruction not in self._tasks:
            # A task line without its episode (crash right after this) is harmless: tasks are a
            # dictionary, and the next episode with this instruction reuses the index.
            _append_jsonl(meta / "tasks.jsonl", {"task_index": task_index, "task": episode.instruction})
            self._tasks[episode.instruction] = task_index
        stats = {STATE_KEY: _stats(episode.states), ACTION_KEY: _stats(episode.actions),
                 AGENT_VIDEO_KEY: _image_stats(episode.agent_images),
                 WRIST_VIDEO_KEY: _image_stats(episode.wrist_images),
                 **{k: _stats(v) for k, v in columns.items()}}
        _append_jsonl(meta / "episodes_stats.jsonl", {"episode_index": index, "stats": stats})

        record = {"episode_index": index, "tasks": [episode.instruction], "length": T,
                  "subplans": list(episode.subplans),
                  "critical_frames": [int(f) for f in episode.critical_frames],
                  "meta": json.loads(json.dumps(episode.meta, default=_json_default))}
        _append_jsonl(meta / "episodes.jsonl", record, sync=True)  # the commit point
        self._episodes.append(record)
        self._total_frames += T
        self._write_info()
        return index

    def _write_info(self) -> None:
        n = len(self._episodes)
        info = {
            "codebase_version": CODEBASE_VERSION,
            "robot_type": self.robot_type,
            "total_episodes": n,
            "total_frames": self._total_frames,
            "total_tasks": len(self._tasks),
            "total_videos": n * len(VIDEO_KEYS),
            "total_chunks": math.ceil(n / CHUNKS_SIZE),
            "chunks_size": CHUNKS_SIZE,
            "fps": self.fps,
            "splits": {"train": f"0:{n}"},
            "data_path": DATA_PATH,
            "video_path": VIDEO_PATH,
            "features": _features(self.fps, self.image_size),
        }
        _write_json_atomic(self.root / "meta" / "info.json", info)

    def close(self) -> None:
        """Release the dataset. Everything added is already on disk."""
        if not self._lock.closed:
            self._lock.close()  # closing the descriptor drops the flock

    def __enter__(self) -> LeRobotWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --------------------------------------------------------------------------------------------
# reader


class LeRobotReader:
    """Reads a LeRobot dataset of codebase_version "v2.1" (as written above) or "v3.0"."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise InvalidInput(f"dataset directory {self.root} does not exist")
        info_path = self.root / "meta" / "info.json"
        if not info_path.exists():
            raise InvalidInput(f"{self.root} is not a LeRobot dataset: it has no meta/info.json")
        self.info: dict = json.loads(info_path.read_text())
        self.version: str = self.info.get("codebase_version", "")
        if self.version == "v2.1":
            # episodes.jsonl, not info.json, is the record of complete episodes (see module doc);
            # a torn last line is an episode still being written and is not shown.
            self._episodes, _ = read_jsonl(self.root / "meta" / "episodes.jsonl")
        elif self.version == "v3.0":
            self._episodes = self._load_v30_episodes()
        else:
            raise InvalidInput(f"{self.root} has codebase_version {self.version!r}; "
                               f"this reader reads 'v2.1' and 'v3.0'")

    @property
    def num_episodes(self) -> int:
        return len(self._episodes)

    @property
    def image_size(self) -> int:
        """Side in px of the camera frames (224 for openpi-view datasets, 64 for a 64-px policy's)."""
        return int(self.info.get("features", {}).get(AGENT_VIDEO_KEY, {}).get("shape", IMAGE_SHAPE)[0])

    def __len__(self) -> int:
        return len(self._episodes)

    @property
    def fps(self) -> int:
        return int(self.info["fps"])

    def _check_index(self, i: int) -> int:
        n = len(self._episodes)
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < n:
            valid = f"0..{n - 1}" if n else "none: the dataset is empty"
            raise InvalidInput(f"episode index {i!r} is out of range for {self.root}; valid: {valid}")
        return int(i)

    def episode_meta(self, i: int) -> dict:
        """The episode's metadata record (the episodes.jsonl line for v2.1)."""
        return dict(self._episodes[self._check_index(i)])

    def frames(self, i: int) -> pa.Table:
        """Episode i's parquet rows (state, action, timestamps, indices); no video is decoded."""
        i = self._check_index(i)
        if self.version == "v2.1":
            path = self.root / self.info["data_path"].format(episode_chunk=i // self.info["chunks_size"],
                                                              episode_index=i)
            if not path.exists():
                raise InvalidInput(f"data file {path} of episode {i} is missing; the dataset is incomplete")
            return pq.read_table(path)
        record = self._episodes[i]
        path = self.root / self.info["data_path"].format(chunk_index=record["data/chunk_index"],
                                                          file_index=record["data/file_index"])
        table = pq.read_table(path)
        return table.filter(pc.equal(table.column("episode_index"), i))

    def video(self, i: int, key: str = AGENT_VIDEO_KEY) -> np.ndarray:
        """One camera of episode i as (T, H, W, 3) uint8, without decoding the other cameras."""
        return self._video(self._check_index(i), key)

    def _video(self, i: int, key: str) -> np.ndarray:
        if key not in self.info.get("features", {}):
            video_keys = [k for k, f in self.info.get("features", {}).items() if f.get("dtype") == "video"]
            raise InvalidInput(f"{self.root} has no video feature {key!r}; it has {video_keys}")
        if self.version == "v2.1":
            return _decode_video(self.root / self.info["video_path"].format(
                episode_chunk=i // self.info["chunks_size"], video_key=key, episode_index=i))
        record = self._episodes[i]
        path = self.root / self.info["video_path"].format(
            video_key=key, chunk_index=record[f"videos/{key}/chunk_index"],
            file_index=record[f"videos/{key}/file_index"])
        return _decode_video(path, start_s=float(record[f"videos/{key}/from_timestamp"]),
                             end_s=float(record[f"videos/{key}/to_timestamp"]))

    def episode(self, i: int) -> Episode:
        """Episode i with both videos decoded (images are lossy: H.264 round trip)."""
        i = self._check_index(i)
        table = self.frames(i)
        T = table.num_rows
        record = self._episodes[i]
        agent, wrist = self._video(i, AGENT_VIDEO_KEY), self._video(i, WRIST_VIDEO_KEY)
        for key, images in ((AGENT_VIDEO_KEY, agent), (WRIST_VIDEO_KEY, wrist)):
            if len(images) != T:
                raise InvalidInput(f"episode {i}: video {key!r} has {len(images)} frames but the data has {T} "
                                   f"rows; the dataset is corrupt")
        meta = record.get("meta") or {}
        if isinstance(meta, str):  # v3.0 parquet cannot hold a free-form dict; JSON text is accepted
            meta = json.loads(meta)
        return Episode(
            instruction=list(record["tasks"])[0],
            agent_images=agent,
            wrist_images=wrist,
            states=fixed_list_to_numpy(table.column(STATE_KEY)),
            actions=fixed_list_to_numpy(table.column(ACTION_KEY)),
            subplans=list(record.get("subplans") or []),
            critical_frames=[int(f) for f in record.get("critical_frames") or []],
            meta=dict(meta),
        )

    def _load_v30_episodes(self) -> list[dict]:
        files = sorted((self.root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
        if not files:
            raise InvalidInput(f"{self.root} is a v3.0 dataset without meta/episodes/chunk-*/file-*.parquet")
        rows = [row for f in files for row in pq.read_table(f).to_pylist()]
        # stats/* columns are bulky per-feature arrays; they are not episode metadata proper
        rows = [{k: v for k, v in row.items() if not k.startswith("stats/")} for row in rows]
        rows.sort(key=lambda r: r["episode_index"])
        for position, row in enumerate(rows):
            if row["episode_index"] != position:
                raise InvalidInput(f"{self.root}: episode indices are not 0..N-1 (found "
                                   f"{row['episode_index']} at position {position})")
        return rows


def fixed_list_to_numpy(column: pa.ChunkedArray) -> np.ndarray:
    array = column.combine_chunks()
    width = array.type.list_size if pa.types.is_fixed_size_list(array.type) else None
    flat = array.flatten().to_numpy(zero_copy_only=False).astype(np.float32, copy=False)
    if width is None:  # variable-size lists (some converters write these); all rows share a length
        width = len(flat) // max(len(array), 1)
    return flat.reshape(len(array), width)


def open_dataset(root: Path) -> LeRobotReader:
    """Open the LeRobot dataset at `root` for reading."""
    return LeRobotReader(root)
