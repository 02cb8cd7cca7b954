"""Training data for a pixel policy: sampled starts, images at the policy's size, lossless storage."""

import numpy as np
import pytest

from seal.datasets import Episode, LeRobotWriter, open_dataset
from seal.demos import record_demos, start_seed
from seal.errors import InvalidInput
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


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    root = tmp_path_factory.mktemp("demos")
    summary = record_demos("libero_10", root, episodes_per_task=1, tasks=[5], render_mode="fast", image_size=64)
    assert summary.recorded == 1
    return root


def test_demos_record_sampled_starts_at_64_px(recorded):
    ds = open_dataset(recorded)
    meta = ds.episode_meta(0)["meta"]
    assert meta["start"] == "sampled" and meta["start_seed"] >= start_seed("libero_10/5", 0)
    assert meta["image_size"] == 64 and ds.image_size == 64
    video = ds.video(0)
    assert video.shape[1:] == (64, 64, 3) and video.std() > 10  # a scene, not a blank frame


def test_demonstrations_replay_into_labelled_verification_cases(recorded, tmp_path):
    """`seal verify from-demos`: the replay reaches the recorded success, every sub-plan is judged
    along its way (not yet achieved half-way, achieved just after its end), and a re-run replays
    nothing."""
    from functools import partial

    from seal.demos import exact_actions
    from seal.verify import dataset as vds
    from seal.verify.demo_cases import DemoCaseOptions
    from seal.verify.demo_cases import from_demos as bare

    from_demos = partial(bare, exact_actions=exact_actions)  # as the CLI calls it
    meta = open_dataset(recorded).episode_meta(0)
    opts = DemoCaseOptions(fractions=(0.5, 1.0), after=5)
    summary = from_demos(recorded, tmp_path, opts)
    assert summary["replay_failed"] == [] and summary["replayed"] == 1 and summary["cases"] > 0
    assert summary["rerun"] == 1  # the expert ran again and gave the recording's exact actions
    stored = np.asarray(open_dataset(recorded).frames(0).column("action").to_pylist(), dtype=np.float64)
    w = LiberoWorld(("libero_10", 5), render_mode="fast")
    try:
        exact = exact_actions(w, meta, stored)
        assert exact is not None and exact.dtype == np.float64
        assert np.array_equal(np.clip(exact, -1, 1).astype(np.float32), stored.astype(np.float32))
        assert not np.array_equal(exact, stored)  # what float32 storage rounded away
        other = stored.copy()
        other[len(other) // 2, 0] += 0.01
        assert exact_actions(w, meta, other) is None  # not this recording: its own actions are kept
        assert exact_actions(w, {**meta, "meta": {**meta["meta"], "dart": 0.1}}, stored) is None
    finally:
        w.close()
    rows = vds.read_cases(tmp_path).to_pylist()
    assert {r["init_source"] for r in rows} == {"demo"} and {r["init_seed"] for r in rows} == {meta["meta"]["start_seed"]}
    for i, text in enumerate(meta["subplans"]):
        mine = sorted((r for r in rows if r["subplan_index"] == i), key=lambda r: r["steps"])
        assert [r["subplan"] for r in mine] == [text] * 3, text
        assert not mine[0]["label"] and mine[-1]["label"], (text, [r["label"] for r in mine])
    first = vds.decode_png(rows[0]["final_agent"])
    assert first.shape == (224, 224, 3) and first.std() > 10
    again = from_demos(recorded, tmp_path, opts)
    assert (again["replayed"], again["already_done"]) == (0, 1)
    with pytest.raises(InvalidInput, match="fractions"):
        from_demos(recorded, tmp_path, DemoCaseOptions(fractions=(0.5,), after=5))
    # a collection made replaying the stored float32 actions continues only that way
    stored = from_demos(recorded, tmp_path / "stored", DemoCaseOptions(fractions=(0.5, 1.0), after=5,
                                                                      rerun_expert=False))
    assert stored["rerun"] == 0 and stored["replayed"] == 1
    with pytest.raises(InvalidInput, match="--replay-stored"):
        from_demos(recorded, tmp_path / "stored", opts)
    with pytest.raises(InvalidInput, match="exact_actions"):
        bare(recorded, tmp_path / "none", opts)
    # a held-out set skips the episodes a training collection used (the fixture has one per task)
    assert from_demos(recorded, tmp_path / "held", DemoCaseOptions(skip_per_task=1))["episodes"] == 0
    with pytest.raises(InvalidInput, match="skip-episodes-per-task"):
        from_demos(recorded, tmp_path / "held", DemoCaseOptions(skip_per_task=-1))

    # near misses: the same replay with two branches per sub-plan
    branched = tmp_path / "branched"
    summary = from_demos(recorded, branched, DemoCaseOptions(fractions=(0.5, 1.0), after=5, branches=2))
    assert summary["replay_failed"] == []  # restoring after each branch keeps the replay on its recording
    with_branches = vds.read_cases(branched).to_pylist()
    plain = {r["case_id"]: r for r in rows}
    on_path = [r for r in with_branches if ":b" not in r["case_id"]]
    assert sorted(r["case_id"] for r in on_path) == sorted(plain)
    for r in on_path:  # the recording's own states, pixel for pixel
        assert r["label"] == plain[r["case_id"]]["label"] and r["final_agent"] == plain[r["case_id"]]["final_agent"]
    branches = [r for r in with_branches if ":b" in r["case_id"]]
    assert 0 < len(branches) <= 2 * len(meta["subplans"])
    assert not all(r["label"] for r in branches)  # 5 cm off the demonstration's hand: some miss
    for r in branches:
        twin = plain[next(k for k in plain if k.startswith(r["case_id"].rsplit(":b", 1)[0] + ":f"))]
        assert r["first_agent"] == twin["first_agent"]  # judged against the sub-plan's own start
    with pytest.raises(InvalidInput, match="branches"):
        from_demos(recorded, branched, DemoCaseOptions(fractions=(0.5, 1.0), after=5))  # another setting
    with pytest.raises(InvalidInput, match="branch-miss"):
        DemoCaseOptions(branches=1, branch_miss=0.0).check()

    # idle-gripper branches: the hand moves as recorded, the gripper keeps its first command
    idle = tmp_path / "idle"
    summary = from_demos(recorded, idle, DemoCaseOptions(fractions=(0.5, 1.0), after=5, grip_branch=True))
    assert summary["replay_failed"] == []
    with_idle = vds.read_cases(idle).to_pylist()
    assert sorted(r["case_id"] for r in with_idle if not r["case_id"].endswith(":g")) == sorted(plain)
    grips = [r for r in with_idle if r["case_id"].endswith(":g")]
    assert 0 < len(grips) <= len(meta["subplans"])
    picks = [r for r in grips if r["subplan"].startswith("pick")]
    assert picks and not any(r["label"] for r in picks)  # an empty hand lifted over the object picks nothing
    alone = from_demos(recorded, tmp_path / "alone", DemoCaseOptions(fractions=(0.5, 1.0), after=5, grip_branch=True,
                                                                       only_branches=True))
    assert alone["cases"] == len(grips) and [r["final_agent"] for r in vds.read_cases(tmp_path / "alone").to_pylist()] \
        == [r["final_agent"] for r in grips]  # the same branches, pixel for pixel, without the recording's states
    with pytest.raises(InvalidInput, match="only-branches"):
        DemoCaseOptions(only_branches=True).check()

    # task-level cases: the instruction at every sub-plan's end and the last frame, by the task's goal
    summary = from_demos(recorded, tmp_path / "task", DemoCaseOptions(fractions=(0.5, 1.0), after=5, task_cases=True,
                                                                        only_branches=True))
    tasks = sorted(vds.read_cases(tmp_path / "task").to_pylist(), key=lambda r: r["steps"])
    assert summary["replay_failed"] == [] and len(tasks) == len(meta["subplans"]) + 1
    from seal.sim.suites import get_task

    assert {r["kind"] for r in tasks} == {"task"}
    assert {r["subplan"] for r in tasks} == {get_task("libero_10", 5).instruction}
    # the book is not in the caddy when the pick ends, and it is at the last frame (once in, it stays)
    labels = [r["label"] for r in tasks]
    assert not labels[0] and labels[-1] and labels == sorted(labels)
    assert [r["steps"] for r in tasks][:-1] == [int(f) for f in meta["critical_frames"]]
    assert all(r["first_agent"] == tasks[0]["first_agent"] for r in tasks)  # the episode's first view
