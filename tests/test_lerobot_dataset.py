"""LeRobot v2.1 dataset writer/reader on synthetic episodes (no simulator)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from _v30 import write_v30

from seal.datasets import Episode, LeRobotReader, LeRobotWriter, open_dataset
from seal.datasets.lerobot import AGENT_VIDEO_KEY, WRIST_VIDEO_KEY
from seal.errors import InvalidInput


def make_episode(T: int, instruction: str = "put the bowl on the plate", seed: int = 0,
                 n_subplans: int = 2) -> Episode:
    """Smooth gradients with a moving square: H.264 keeps these within a few grey levels."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:224, 0:224]
    agent = np.empty((T, 224, 224, 3), np.uint8)
    wrist = np.empty((T, 224, 224, 3), np.uint8)
    for t in range(T):
        agent[t, ..., 0] = (x + 3 * t + seed * 10) % 256
        agent[t, ..., 1] = y
        agent[t, ..., 2] = (x + y) // 2
        agent[t, 60 + 2 * t:100 + 2 * t, 40 + t:80 + t] = (200, 40, 40)
        wrist[t] = 255 - agent[t]
    return Episode(
        instruction=instruction,
        agent_images=agent,
        wrist_images=wrist,
        states=rng.normal(size=(T, 8)).astype(np.float32),
        actions=rng.uniform(-1, 1, size=(T, 7)).astype(np.float32),
        subplans=[f"step {k} of {instruction}" for k in range(n_subplans)],
        critical_frames=[min(3 * (k + 1), T - 1) if k % 2 == 0 else -1 for k in range(n_subplans)],
        meta={"suite": "libero_10", "task_id": seed, "init_index": 7, "success": seed % 2 == 0, "seed": seed},
    )


def assert_same(read: Episode, written: Episode) -> None:
    assert read.instruction == written.instruction
    np.testing.assert_array_equal(read.states, written.states)
    np.testing.assert_array_equal(read.actions, written.actions)
    assert read.states.dtype == np.float32 and read.actions.dtype == np.float32
    assert read.subplans == written.subplans
    assert read.critical_frames == written.critical_frames
    assert read.meta == written.meta
    for got, want in ((read.agent_images, written.agent_images), (read.wrist_images, written.wrist_images)):
        assert got.shape == want.shape and got.dtype == want.dtype
        assert np.abs(got.astype(np.int16) - want).mean() < 3


def jsonl(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_round_trip(tmp_path):
    episodes = [make_episode(12, "open the drawer", seed=0),
                make_episode(20, "put the bowl on the plate", seed=1, n_subplans=3),
                make_episode(7, "open the drawer", seed=2, n_subplans=0)]
    with LeRobotWriter(tmp_path / "ds", fps=20) as writer:
        assert [writer.add(e) for e in episodes] == [0, 1, 2]
        assert writer.num_episodes == 3

    root = tmp_path / "ds"
    reader = open_dataset(root)
    assert reader.num_episodes == 3 and reader.fps == 20
    for i, written in enumerate(episodes):
        assert_same(reader.episode(i), written)

    info = reader.info
    assert info["codebase_version"] == "v2.1" and info["robot_type"] == "panda"
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (3, 39, 2)
    assert (info["total_videos"], info["total_chunks"], info["chunks_size"]) == (6, 1, 1000)
    assert info["splits"] == {"train": "0:3"}
    assert info["features"][AGENT_VIDEO_KEY]["dtype"] == "video"
    assert info["features"][AGENT_VIDEO_KEY]["info"]["video.codec"] == "h264"
    assert info["features"]["observation.state"]["shape"] == [8]

    assert jsonl(root / "meta/tasks.jsonl") == [{"task_index": 0, "task": "open the drawer"},
                                                {"task_index": 1, "task": "put the bowl on the plate"}]
    ep1 = reader.episode_meta(1)
    assert (ep1["episode_index"], ep1["tasks"], ep1["length"]) == (1, ["put the bowl on the plate"], 20)
    stats = jsonl(root / "meta/episodes_stats.jsonl")
    assert [s["episode_index"] for s in stats] == [0, 1, 2]
    assert stats[1]["stats"]["action"]["count"] == [20]
    assert np.allclose(stats[1]["stats"]["observation.state"]["mean"], episodes[1].states.mean(0), atol=1e-6)
    assert np.array(stats[1]["stats"][AGENT_VIDEO_KEY]["mean"]).shape == (3, 1, 1)

    for key in (AGENT_VIDEO_KEY, WRIST_VIDEO_KEY):
        assert (root / f"videos/chunk-000/{key}/episode_000002.mp4").is_file()
    table = pq.read_table(root / "data/chunk-000/episode_000001.parquet")
    assert table.schema.names == ["observation.state", "action", "timestamp", "frame_index",
                                  "episode_index", "index", "task_index"]
    assert table.schema.field("observation.state").type == pa.list_(pa.float32(), 8)
    assert table.schema.field("action").type == pa.list_(pa.float32(), 7)
    assert table.schema.field("timestamp").type == pa.float32()
    assert table.schema.field("task_index").type == pa.int64()
    assert table.column("index").to_pylist() == list(range(12, 32))
    assert table.column("episode_index").to_pylist() == [1] * 20
    assert table.column("task_index").to_pylist() == [1] * 20
    np.testing.assert_allclose(table.column("timestamp").to_numpy(), np.arange(20) / 20, atol=1e-6)
    assert reader.frames(1).equals(table)


def test_resume_and_crash_recovery(tmp_path):
    root = tmp_path / "ds"
    with LeRobotWriter(root) as writer:
        writer.add(make_episode(5, seed=0))
        writer.add(make_episode(6, seed=1))
    with LeRobotWriter(root) as writer:
        assert writer.num_episodes == 2
        assert writer.add(make_episode(4, seed=2)) == 2
    reader = LeRobotReader(root)
    assert reader.num_episodes == 3 and reader.info["total_frames"] == 15
    assert [reader.episode_meta(i)["episode_index"] for i in range(3)] == [0, 1, 2]
    assert reader.frames(2).column("index").to_pylist() == [11, 12, 13, 14]

    # A crash while writing episode 3: its files and stats line exist, its episodes.jsonl line
    # is torn, and a temp file was left behind.
    orphans = [root / "data/chunk-000/episode_000003.parquet",
               root / f"videos/chunk-000/{AGENT_VIDEO_KEY}/episode_000003.mp4",
               root / f"videos/chunk-000/{WRIST_VIDEO_KEY}/episode_000003.mp4.tmp"]
    shutil.copy(root / "data/chunk-000/episode_000002.parquet", orphans[0])
    shutil.copy(root / f"videos/chunk-000/{AGENT_VIDEO_KEY}/episode_000002.mp4", orphans[1])
    orphans[2].write_bytes(b"partial")
    with (root / "meta/episodes_stats.jsonl").open("a") as f:
        f.write(json.dumps({"episode_index": 3, "stats": {}}) + "\n")
    with (root / "meta/episodes.jsonl").open("a") as f:
        f.write('{"episode_index": 3, "tasks": ["put')
    assert LeRobotReader(root).num_episodes == 3  # readers skip the torn line too

    with LeRobotWriter(root) as writer:
        assert writer.num_episodes == 3
        assert not any(p.exists() for p in orphans)
        assert [s["episode_index"] for s in jsonl(root / "meta/episodes_stats.jsonl")] == [0, 1, 2]
        fresh = make_episode(8, "open the drawer", seed=3)
        assert writer.add(fresh) == 3
    reader = LeRobotReader(root)
    assert reader.num_episodes == 4 and reader.info["total_frames"] == 23
    assert reader.frames(3).column("index").to_pylist() == list(range(15, 23))
    assert_same(reader.episode(3), fresh)
    assert_same(reader.episode(2), make_episode(4, seed=2))


def test_writer_refuses_incompatible_directories(tmp_path):
    root = tmp_path / "ds"
    with LeRobotWriter(root, fps=20):
        pass
    with pytest.raises(InvalidInput, match=r"fps is 20 there, 10 requested"):
        LeRobotWriter(root, fps=10)
    with pytest.raises(InvalidInput, match=r"robot_type is 'panda' there, 'ur5' requested"):
        LeRobotWriter(root, robot_type="ur5")
    with LeRobotWriter(root), pytest.raises(InvalidInput, match="already open"):
        LeRobotWriter(root)

    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("hello")
    with pytest.raises(InvalidInput, match="not a LeRobot dataset"):
        LeRobotWriter(other)

    v30 = tmp_path / "v30"
    (v30 / "meta").mkdir(parents=True)
    (v30 / "meta/info.json").write_text(json.dumps({"codebase_version": "v3.0", "fps": 20}))
    with pytest.raises(InvalidInput, match="codebase_version 'v3.0'"):
        LeRobotWriter(v30)


def _broken(change: dict) -> Episode:
    e = make_episode(6)
    for name, value in change.items():
        setattr(e, name, value(e) if callable(value) else value)
    return e


@pytest.mark.parametrize("change, message", [
    ({"agent_images": lambda e: e.agent_images[:, :112]}, r"agent_images has shape \(6, 112, 224, 3\); expected \(6, 224, 224, 3\) uint8"),
    ({"wrist_images": lambda e: e.wrist_images.astype(np.float32)}, r"wrist_images has dtype float32; expected .* uint8"),
    ({"states": lambda e: e.states.astype(np.float64)}, r"states has dtype float64; expected \(T, 8\) float32"),
    ({"actions": lambda e: e.actions[:, :6]}, r"actions has shape \(6, 6\); expected \(6, 7\) float32"),
    ({"actions": lambda e: e.actions[:5]}, r"actions has 5 frames but Episode.states has 6"),
    ({"wrist_images": lambda e: e.wrist_images[:4]}, r"wrist_images has 4 frames but Episode.states has 6"),
    ({"actions": lambda e: e.actions * 3}, r"actions must be finite and in \[-1, 1\]"),
    ({"critical_frames": [2]}, r"2 subplans but 1 critical_frames"),
    ({"critical_frames": [2, 6]}, r"critical_frames\[1\] is 6; expected a frame index in \[0, 5\] or -1"),
    ({"instruction": ""}, r"instruction must be a non-empty string"),
    ({"meta": {"f": object()}}, r"meta must be JSON-serializable"),
])
def test_add_rejects_bad_episodes_before_writing(tmp_path, change, message):
    with LeRobotWriter(tmp_path / "ds") as writer:
        with pytest.raises(InvalidInput, match=message):
            writer.add(_broken(change))
        assert writer.num_episodes == 0
    assert not (tmp_path / "ds/data").exists() and not (tmp_path / "ds/videos").exists()


def test_reader_errors(tmp_path):
    with pytest.raises(InvalidInput, match="does not exist"):
        LeRobotReader(tmp_path / "missing")
    (tmp_path / "plain").mkdir()
    with pytest.raises(InvalidInput, match="no meta/info.json"):
        open_dataset(tmp_path / "plain")
    with LeRobotWriter(tmp_path / "ds") as writer:
        writer.add(make_episode(3))
        writer.add(make_episode(3))
    reader = LeRobotReader(tmp_path / "ds")
    for bad in (2, -1):
        with pytest.raises(InvalidInput, match=r"episode index .* out of range .* valid: 0\.\.1"):
            reader.episode(bad)
    with pytest.raises(InvalidInput, match="out of range"):
        reader.frames(5)


def test_reads_v30_layout(tmp_path):
    """A two-episode v3.0 dataset built by hand: one data file, one concatenated mp4 per camera."""
    root, fps = tmp_path / "v30", 20
    episodes = [make_episode(9, "open the drawer", seed=0), make_episode(6, "close the drawer", seed=1)]
    write_v30(root, episodes, fps, lambda i, e: {"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0,
                                                  "stats/action/mean": e.actions.mean(0).tolist()})

    reader = open_dataset(root)
    assert reader.num_episodes == 2
    assert "stats/action/mean" not in reader.episode_meta(0)
    assert reader.frames(1).column("index").to_pylist() == list(range(9, 15))
    for i, written in enumerate(episodes):
        read = reader.episode(i)
        assert (read.subplans, read.critical_frames, read.meta) == ([], [], {})
        assert_same(read, Episode(written.instruction, written.agent_images, written.wrist_images,
                                  written.states, written.actions))
