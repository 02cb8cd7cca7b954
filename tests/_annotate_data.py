"""Small synthetic LeRobot datasets for the annotation tests (where simulator realism is not the point).

Each episode has a moving square on a gradient (H.264 keeps it recognisable) and recorded
sub-plans with the frame where each first held, as `seal demos record` writes them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from seal.datasets import Episode, LeRobotWriter
from seal.datasets.lerobot import AGENT_VIDEO_KEY, WRIST_VIDEO_KEY, _encode_video

PLANS = ["pick up the black bowl", "place it on the plate", "pick up the mug", "place it on the plate"]


def synthetic_episode(T: int, seed: int, instruction: str = "put the bowl and the mug on the plate") -> Episode:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:224, 0:224]
    agent = np.empty((T, 224, 224, 3), np.uint8)
    for t in range(T):
        agent[t, ..., 0] = (x + 3 * t) % 256
        agent[t, ..., 1] = y
        agent[t, ..., 2] = (x + y) // 2
        agent[t, 40 + t % 100:80 + t % 100, 30 + seed * 5:70 + seed * 5] = (220, 30, 30)
    # Four sub-goals spread over the episode; odd frames on purpose (they fall between 10 fps frames).
    frames = sorted(int(f) for f in np.linspace(T * 0.2, T - 1, 4).round().astype(int) + seed % 2)
    frames = [min(f, T - 1) for f in frames]
    return Episode(instruction=instruction, agent_images=agent, wrist_images=255 - agent,
                   states=rng.normal(size=(T, 8)).astype(np.float32),
                   actions=rng.uniform(-1, 1, size=(T, 7)).astype(np.float32),
                   subplans=list(PLANS), critical_frames=frames,
                   meta={"suite": "synthetic", "task_id": 0, "init_index": seed})


def make_v21(root: Path, lengths: list[int]) -> list[Episode]:
    episodes = [synthetic_episode(T, seed=i) for i, T in enumerate(lengths)]
    with LeRobotWriter(root, fps=20) as w:
        for e in episodes:
            w.add(e)
    return episodes


def make_v30(root: Path, lengths: list[int], fps: int = 20) -> list[Episode]:
    """A v3.0 layout by hand (no v3.0 writer exists): one data file, one concatenated mp4 per
    camera, episode metadata in parquet (sub-plans and critical frames as extra columns)."""
    episodes = [synthetic_episode(T, seed=i, instruction=f"task number {i}") for i, T in enumerate(lengths)]
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
        _encode_video(np.concatenate([getattr(e, attr) for e in episodes]),
                      root / f"videos/{key}/chunk-000/file-000.mp4", fps)
    rows = []
    for i, e in enumerate(episodes):
        row = {"episode_index": i, "tasks": [e.instruction], "length": e.length,
               "data/chunk_index": 0, "data/file_index": 0,
               "dataset_from_index": int(starts[i]), "dataset_to_index": int(starts[i] + e.length),
               "subplans": e.subplans, "critical_frames": e.critical_frames}
        for key in (AGENT_VIDEO_KEY, WRIST_VIDEO_KEY):
            row |= {f"videos/{key}/chunk_index": 0, f"videos/{key}/file_index": 0,
                    f"videos/{key}/from_timestamp": starts[i] / fps,
                    f"videos/{key}/to_timestamp": (starts[i] + e.length) / fps}
        rows.append(row)
    (root / "meta/episodes/chunk-000").mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist(rows), root / "meta/episodes/chunk-000/file-000.parquet")
    video = {"dtype": "video", "shape": [224, 224, 3], "names": ["height", "width", "channels"]}
    (root / "meta/info.json").write_text(json.dumps({
        "codebase_version": "v3.0", "fps": fps, "robot_type": "panda", "total_episodes": len(lengths),
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
        "features": {AGENT_VIDEO_KEY: video, WRIST_VIDEO_KEY: video}}))
    return episodes
