"""An episode's agent view as the 10 fps clip an annotator watches, and the exact frame mapping.

Resampling rule: video frame ``v`` (time ``v / 10`` s) shows the last dataset frame recorded at
or before that time, ``d = floor(v * dataset_fps / 10)``. The clip ends at the last video frame
that still has a dataset frame, so ``n = floor((T - 1) * 10 / dataset_fps) + 1`` frames. For a
20 fps dataset that is every second frame (``d = 2 v``).

Going back: a model's "step finished at video frame v" means dataset frame ``d(v)``. Exact
dataset frames (the expert's ground truth) go the other way with :meth:`FrameMap.first_showing`,
the first video frame that shows dataset frame ``d`` or a later one: an annotator watching the
clip cannot see a sub-goal finish any earlier.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from seal.datasets.lerobot import AGENT_VIDEO_KEY, LeRobotReader, encode_video
from seal.errors import InvalidInput

VIDEO_FPS = 10  # the rate the annotation prompt talks about (the seed's template uses 10 fps)


@dataclass(frozen=True)
class FrameMap:
    """Which dataset frame each 10 fps video frame shows."""

    dataset_fps: int
    length: int  # dataset frames T in the episode
    video_fps: int = VIDEO_FPS

    def __post_init__(self) -> None:
        for name in ("dataset_fps", "length", "video_fps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise InvalidInput(f"FrameMap.{name} must be a positive integer, got {value!r}")

    @property
    def num_video_frames(self) -> int:
        return (self.length - 1) * self.video_fps // self.dataset_fps + 1

    def dataset_frame(self, v: int) -> int:
        """The dataset frame shown at video frame ``v``."""
        if not 0 <= v < self.num_video_frames:
            raise InvalidInput(f"video frame {v} is outside the clip; valid: 0..{self.num_video_frames - 1}")
        return v * self.dataset_fps // self.video_fps

    def first_showing(self, d: int) -> int:
        """The first video frame showing dataset frame ``d`` or a later one (clipped to the clip)."""
        if not 0 <= d < self.length:
            raise InvalidInput(f"dataset frame {d} is outside the episode; valid: 0..{self.length - 1}")
        return min(-(-d * self.video_fps // self.dataset_fps), self.num_video_frames - 1)

    def time_of(self, v: int) -> float:
        """Seconds into the clip of video frame ``v`` (rounded to the millisecond)."""
        return round(v / self.video_fps, 3)

    def dataset_frames(self) -> list[int]:
        """The whole mapping, video frame -> dataset frame (what annotations.jsonl stores)."""
        return [self.dataset_frame(v) for v in range(self.num_video_frames)]

    def to_dict(self) -> dict:
        return {"dataset_fps": self.dataset_fps, "video_fps": self.video_fps, "length": self.length,
                "video_to_dataset": self.dataset_frames()}


def resample(frames: np.ndarray, frame_map: FrameMap) -> np.ndarray:
    """The clip's frames, (n, H, W, 3), picked from the episode's frames (T, H, W, 3)."""
    if len(frames) != frame_map.length:
        raise InvalidInput(f"got {len(frames)} frames for an episode of {frame_map.length}")
    return frames[np.asarray(frame_map.dataset_frames(), dtype=np.int64)]


def write_clip(frames: np.ndarray, path: Path, fps: int = VIDEO_FPS) -> Path:
    """Encode ``frames`` as an H.264 mp4 (atomically: temp file + rename)."""
    encode_video(np.ascontiguousarray(frames), Path(path), fps)
    return Path(path)


# --------------------------------------------------------------------------- dataset access


def camera_key(reader: LeRobotReader, requested: str | None = None) -> str:
    """The image feature to annotate: ``requested``, else the agent view this project writes,
    else the only non-wrist camera of the dataset."""
    features = reader.info.get("features", {})
    cameras = [k for k, f in features.items() if f.get("dtype") in ("video", "image")]
    if requested is not None:
        if requested not in cameras:
            raise InvalidInput(f"{reader.root} has no camera {requested!r}; its cameras: {cameras}")
        return requested
    if AGENT_VIDEO_KEY in cameras:
        return AGENT_VIDEO_KEY
    front = [k for k in cameras if "wrist" not in k.lower()]
    if len(front) == 1:
        return front[0]
    raise InvalidInput(f"cannot tell which camera of {reader.root} is the agent view among {cameras}; "
                       f"pass camera= (--camera) with one of them")


def load_frames(reader: LeRobotReader, episode: int, key: str) -> np.ndarray:
    """All frames of one camera of one episode, (T, H, W, 3) uint8.

    Video features are decoded from their mp4; "image" features (LeRobot datasets that store
    PNG/JPEG bytes in the parquet rows) are decoded row by row.
    """
    feature = reader.info.get("features", {}).get(key, {})
    if feature.get("dtype") == "video":
        return reader.video(episode, key)
    from PIL import Image

    column = reader.frames(episode).column(key)
    images = []
    for n, cell in enumerate(column.to_pylist()):
        data = cell.get("bytes") if isinstance(cell, dict) else cell
        if not isinstance(data, (bytes, bytearray)):
            raise InvalidInput(f"episode {episode}: row {n} of image column {key!r} holds no image bytes")
        images.append(np.asarray(Image.open(io.BytesIO(data)).convert("RGB")))
    if not images:
        raise InvalidInput(f"episode {episode} of {reader.root} has no frames")
    return np.stack(images)


def episode_length(reader: LeRobotReader, episode: int) -> int:
    """T from the episode record, or from the parquet rows when the record lacks it."""
    meta = reader.episode_meta(episode)
    if "length" in meta:
        return int(meta["length"])
    table: pa.Table = reader.frames(episode)
    return table.num_rows


def episode_instruction(reader: LeRobotReader, episode: int) -> str:
    tasks = reader.episode_meta(episode).get("tasks") or []
    if isinstance(tasks, str):
        tasks = [tasks]
    if not tasks or not str(tasks[0]).strip():
        raise InvalidInput(f"episode {episode} of {reader.root} has no task instruction")
    return str(tasks[0])
