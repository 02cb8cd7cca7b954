"""A LeRobot v3.0 dataset written by hand for reader tests (the project writes v2.1 only).

v3.0 concatenates episodes: one parquet data file, one mp4 per camera holding every episode
back to back, and episode metadata as parquet rows that point into both.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from seal.datasets import Episode
from seal.datasets.lerobot import AGENT_VIDEO_KEY, WRIST_VIDEO_KEY, encode_video


def write_v30(root: Path, episodes: list[Episode], fps: int = 20,
              extra_columns: Callable[[int, Episode], dict] = lambda i, e: {}) -> None:
    """Write ``episodes`` under ``root``; ``extra_columns(i, episode)`` adds episode-metadata columns."""
    lengths = [e.length for e in episodes]
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(int)
    data = root / "data/chunk-000/file-000.parquet"
    data.parent.mkdir(parents=True)
    pq.write_table(pa.table({
        "observation.state": pa.FixedSizeListArray.from_arrays(
            pa.array(np.concatenate([e.states for e in episodes]).ravel()), 8),
        "action": pa.FixedSizeListArray.from_arrays(pa.array(np.concatenate([e.actions for e in episodes]).ravel()), 7),
        "timestamp": pa.array(np.concatenate([np.arange(n) / fps for n in lengths]).astype(np.float32)),
        "frame_index": pa.array(np.concatenate([np.arange(n) for n in lengths])),
        "episode_index": pa.array(np.repeat(np.arange(len(lengths)), lengths)),
        "index": pa.array(np.arange(sum(lengths))),
        "task_index": pa.array(np.repeat(np.arange(len(lengths)), lengths)),
    }), data)
    for key, attr in ((AGENT_VIDEO_KEY, "agent_images"), (WRIST_VIDEO_KEY, "wrist_images")):
        encode_video(np.concatenate([getattr(e, attr) for e in episodes]),
                      root / f"videos/{key}/chunk-000/file-000.mp4", fps)
    rows = []
    for i, e in enumerate(episodes):
        row = {"episode_index": i, "tasks": [e.instruction], "length": e.length,
               "data/chunk_index": 0, "data/file_index": 0,
               "dataset_from_index": int(starts[i]), "dataset_to_index": int(starts[i] + e.length)}
        for key in (AGENT_VIDEO_KEY, WRIST_VIDEO_KEY):
            row |= {f"videos/{key}/chunk_index": 0, f"videos/{key}/file_index": 0,
                    f"videos/{key}/from_timestamp": starts[i] / fps,
                    f"videos/{key}/to_timestamp": (starts[i] + e.length) / fps}
        rows.append(row | extra_columns(i, e))
    (root / "meta/episodes/chunk-000").mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist(rows), root / "meta/episodes/chunk-000/file-000.parquet")
    video = {"dtype": "video", "shape": [224, 224, 3], "names": ["height", "width", "channels"]}
    (root / "meta/info.json").write_text(json.dumps({
        "codebase_version": "v3.0", "fps": fps, "robot_type": "panda", "total_episodes": len(episodes),
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
        "features": {AGENT_VIDEO_KEY: video, WRIST_VIDEO_KEY: video}}))
