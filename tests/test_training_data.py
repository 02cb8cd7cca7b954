"""Training data for a pixel policy: sampled starts, images at the policy's size, lossless storage."""

import numpy as np
import pytest

from seal.datasets import Episode, LeRobotWriter, open_dataset
from seal.demos import record_demos, start_seed
from seal.sim.world import LiberoWorld


@pytest.fixture(scope="module")
def world():
    w = LiberoWorld(("libero_10", 3), render_mode="fast")
    yield w
    w.close()


def test_sampled_starts_are_seeded_and_never_an_official_state(world):
    official = world.init_states
    nq = world.model.nq
    used = world.reset_sampled(5000, settle=False)
    a, fixtures_a = world.data.qpos.copy(), world.snapshot().fixtures.copy()
    world.reset_sampled(5000, settle=False)
    assert np.array_equal(a, world.data.qpos) and np.array_equal(fixtures_a, world.snapshot().fixtures)  # same seed, same start
    world.reset_sampled(used + 1, settle=False)
    c = world.data.qpos.copy()
    assert not np.allclose(a, c)  # objects moved
    assert not np.allclose(fixtures_a, world.snapshot().fixtures)  # and the cabinet stands elsewhere
    for q in (a, c):
        assert np.min(np.abs(official[:, 1:1 + nq] - q).max(axis=1)) > 1e-3


def test_images_rendered_at_the_policy_size_in_openpis_orientation(world):
    world.reset(0)
    small = world.observe(images=64)
    big = world.observe(images=True)
    assert small.agent.shape == small.wrist.shape == (64, 64, 3) and big.agent.shape == (224, 224, 3)
    # same view, same orientation: the 224 view shrunk to 64 matches far better than its mirror
    from PIL import Image

    shrunk = np.asarray(Image.fromarray(big.agent).resize((64, 64), Image.BILINEAR)).astype(float)
    err = np.abs(shrunk - small.agent).mean()
    err_mirrored = np.abs(shrunk[:, ::-1] - small.agent).mean()
    assert err < 0.5 * err_mirrored
    # a renderer per size: switching back and forth gives the same pixels
    assert np.array_equal(world.observe(images=64).agent, small.agent)
    with pytest.raises(Exception, match="out of range"):
        world.observe(images=8)


def test_small_datasets_store_frames_losslessly(tmp_path):
    rng = np.random.default_rng(0)
    T = 6
    frames = rng.integers(0, 256, (T, 64, 64, 3), dtype=np.uint8)  # noise: any lossy codec would show
    ep = Episode(instruction="do it", agent_images=frames, wrist_images=frames[::-1].copy(),
                 states=np.zeros((T, 8), np.float32), actions=np.zeros((T, 7), np.float32))
    with LeRobotWriter(tmp_path / "d", image_size=64) as w:
        w.add(ep)
    ds = open_dataset(tmp_path / "d")
    assert ds.image_size == 64
    assert np.array_equal(ds.video(0), frames)
    with pytest.raises(Exception, match="image_size"):
        LeRobotWriter(tmp_path / "e", image_size=0)
    with pytest.raises(Exception, match=r"\[64, 64, 3\] there"):
        with LeRobotWriter(tmp_path / "d", image_size=224) as w:  # a 224 writer on a 64-px dataset
            pass


def test_demos_record_sampled_starts_at_64_px(tmp_path):
    summary = record_demos("libero_10", tmp_path, episodes_per_task=1, tasks=[5], render_mode="fast",
                           image_size=64)
    assert summary.recorded == 1
    ds = open_dataset(tmp_path)
    meta = ds.episode_meta(0)["meta"]
    assert meta["start"] == "sampled" and meta["start_seed"] >= start_seed("libero_10/5", 0)
    assert meta["image_size"] == 64 and ds.image_size == 64
    video = ds.video(0)
    assert video.shape[1:] == (64, 64, 3) and video.std() > 10  # a scene, not a blank frame
