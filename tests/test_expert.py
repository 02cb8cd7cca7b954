import numpy as np
import pytest

from seal.datasets import open_dataset
from seal.demos import record_demos
from seal.episode import Recording, run_policy_episode
from seal.errors import InvalidInput
from seal.policies.expert.plan import decompose, plan_task
from seal.policies.expert.policy import FailureKnobs, ScriptedExpert
from seal.sim.goals import GoalAtom
from seal.sim.suites import get_task, list_tasks
from seal.sim.world import LiberoWorld

LIBERO_10_PLANS = {
    0: ["pick up the alphabet soup", "place it in the basket", "pick up the tomato sauce", "place it in the basket"],
    1: ["pick up the cream cheese box", "place it in the basket", "pick up the butter", "place it in the basket"],
    2: ["turn on the stove", "pick up the moka pot", "place it on the stove"],
    3: ["pick up the black bowl", "place it in the bottom drawer", "close the bottom drawer"],
    4: ["pick up the white mug", "place it on the left plate", "pick up the yellow and white mug",
        "place it on the right plate"],
    5: ["pick up the book", "place it in the back compartment of the caddy"],
    6: ["pick up the white mug", "place it on the plate", "pick up the chocolate pudding",
        "place it to the right of the plate"],
    7: ["pick up the alphabet soup", "place it in the basket", "pick up the cream cheese box", "place it in the basket"],
    8: ["pick up the first moka pot", "place it on the stove", "pick up the second moka pot", "place it on the stove",
        "turn on the stove"],
    9: ["pick up the yellow and white mug", "place it in the microwave", "close the microwave"],
}


@pytest.mark.parametrize("task_id", range(10))
def test_libero_10_decomposition(task_id):
    plans = plan_task(get_task("libero_10", task_id))
    assert [p.text for p in plans] == LIBERO_10_PLANS[task_id]
    for p in plans:  # every sub-plan is tied to a checkable sub-goal
        assert p.goal.predicate in ("grasped", "in", "on", "close", "turnon")


def test_every_libero_90_task_decomposes_with_dependencies_in_order():
    for spec in list_tasks("libero_90"):
        plans = plan_task(spec)
        assert plans, spec.key
        texts = [p.text for p in plans]
        for i, p in enumerate(plans):
            if p.skill == "place":
                assert plans[i - 1].skill == "pick" and plans[i - 1].obj == p.obj
            if p.skill == "close" and any(q.skill == "place" and q.target == p.obj for q in plans):
                assert i == len(plans) - 1, texts  # put in, then close
    # open before put-in (libero_90/8), and the container moves before the stack (libero_90/63)
    assert [p.skill for p in plan_task(get_task("libero_90", 8))] == ["open", "pick", "place"]
    stack = plan_task(get_task("libero_90", 63))
    assert stack[1].target == "wooden_tray_1_contain_region" and stack[3].target == "akita_black_bowl_2"


def test_unsupported_predicate_fails_fast():
    with pytest.raises(InvalidInput, match=r"unsupported predicate Grasped \(Grasped\(a_1\)\) in task libero_10/0"):
        decompose([GoalAtom.parse("Grasped(a_1)")], "hold it", ["a_1"], task="libero_10/0")


@pytest.fixture(scope="module")
def book_world():
    w = LiberoWorld(("libero_10", 5))
    yield w
    w.close()


def test_expert_solves_the_book_task_and_reasons_in_three_fields(book_world):
    policy = ScriptedExpert.for_world(book_world)
    result = run_policy_episode(book_world, policy, init_index=0)
    assert result.success and not result.sim_error and result.steps < 200
    assert result.subplans == LIBERO_10_PLANS[5]
    assert 0 < result.critical_frames[0] < result.critical_frames[1] <= result.steps
    first = result.reasoning[0][1]
    assert first.startswith("Plans: 1. pick up the book.") and "What has been done: nothing yet." in first
    assert "Now I need to do: pick up the book." in first
    assert "Now I need to do: place it in the back compartment of the caddy." in result.reasoning[1][1]


def test_a_pixel_policy_gets_its_cameras_without_a_recording(book_world):
    # A policy that declares an image size (a learned VLA) is shown both cameras at that size in a
    # plain episode too, not only when frames are recorded.
    from seal.benchmarks.steer import PixelReadingExpert

    policy = PixelReadingExpert(ScriptedExpert.for_world(book_world), 32)
    asked = []
    observe = book_world.observe

    def counting(*a, **kw):
        asked.append(kw.get("images"))
        return observe(*a, **kw)

    book_world.observe = counting
    try:
        result = run_policy_episode(book_world, policy, init_index=0, max_steps=10)
    finally:
        del book_world.observe
    assert result.steps == 10 and policy.pixels_read == 2 * 32 * 32 * 3 * 2  # two chunks, two cameras
    # rendered only where the policy looks: the start and each chunk's last step, not the 8 in between
    assert asked.count(32) == 3 and asked.count(False) == 8
    with pytest.raises(InvalidInput, match="record at image_size=32"):
        run_policy_episode(book_world, policy, init_index=0, max_steps=5, recording=Recording(), image_size=64)


def _first_chunks(world, knobs, seed, n=3):
    policy = ScriptedExpert.for_world(world, knobs, seed=seed)
    world.reset(0)
    policy.reset(seed=seed)
    atoms = policy.privileged_atoms()
    obs = world.observe(images=False, privileged_atoms=atoms)
    reasoning = policy.reason(obs)
    policy.begin(2)
    out = []
    for _ in range(n):
        chunks = policy.act([obs, obs], reasoning)
        out.append(np.stack([c.actions for c in chunks]))
        world.step_chunk(np.clip(chunks[0].actions[:5], -1, 1))
        obs = world.observe(images=False, privileged_atoms=atoms)
    return np.stack(out)


def test_failure_knobs_are_seeded(book_world):
    knobs = FailureKnobs.misaligned()
    a = _first_chunks(book_world, knobs, seed=3)
    b = _first_chunks(book_world, knobs, seed=3)
    c = _first_chunks(book_world, knobs, seed=4)
    assert np.array_equal(a, b)  # same seed, same rollout
    assert not np.array_equal(a, c)
    assert not np.array_equal(a[:, 0], a[:, 1])  # K rows of one round differ from each other
    clean = _first_chunks(book_world, FailureKnobs(), seed=3)
    assert np.array_equal(clean[:, 0], clean[:, 1])  # no knobs: candidates agree
    with pytest.raises(InvalidInput, match="valid: clean, misaligned"):
        FailureKnobs.named("sloppy")


def test_demos_record_writes_lerobot_and_resumes(tmp_path):
    summary = record_demos("libero_10", tmp_path, episodes_per_task=1, tasks=[5])
    assert (summary.recorded, summary.failed) == (1, 0)
    again = record_demos("libero_10", tmp_path, episodes_per_task=1, tasks=[5])
    assert (again.recorded, again.skipped) == (0, 1)
    ds = open_dataset(tmp_path)
    ep = ds.episode(0)
    assert ds.num_episodes == 1 and ep.subplans == LIBERO_10_PLANS[5]
    assert ep.agent_images.shape == (ep.length, 224, 224, 3) and ep.states.shape == (ep.length, 8)
    assert 0 < ep.critical_frames[0] < ep.critical_frames[1] < ep.length
    assert ds.episode_meta(0)["meta"]["init_index"] == 0 and ds.episode_meta(0)["meta"]["success"] is True


def test_dart_perturbs_what_is_executed_not_what_is_recorded(book_world, tmp_path):
    runs = {}
    for dart in (0.0, 0.3):
        rec = Recording()
        run_policy_episode(book_world, ScriptedExpert.for_world(book_world), init_index=0, max_steps=15,
                           recording=rec, image_size=32, dart=dart)
        runs[dart] = (np.stack(rec.states), np.stack(rec.actions))
    (s0, a0), (s1, a1) = runs[0.0], runs[0.3]
    assert np.array_equal(a0[:5], a1[:5])  # the first chunk's labels are the expert's, unperturbed
    assert np.array_equal(s0[0], s1[0]) and not np.allclose(s0[5], s1[5], atol=1e-3)  # ...but not what ran
    with pytest.raises(InvalidInput, match="dart must be a noise std"):
        run_policy_episode(book_world, ScriptedExpert.for_world(book_world), init_index=0, dart=-0.1)
    (tmp_path / "meta").mkdir()
    (tmp_path / "meta" / "seal_attempts.jsonl").write_text(
        '{"suite": "libero_10", "task_id": 5, "init_index": 0, "success": true}\n')
    with pytest.raises(InvalidInput, match="recorded with --dart 0.0, not 0.1"):
        record_demos("libero_10", tmp_path, episodes_per_task=1, tasks=[5], dart=0.1)


def test_demos_record_refuses_bad_counts_before_any_work(tmp_path):
    with pytest.raises(InvalidInput, match="must be in 1..50, got 51"):
        record_demos("libero_10", tmp_path / "d", episodes_per_task=51, tasks=[5], starts="official")
    with pytest.raises(InvalidInput, match="got 0"):
        record_demos("libero_10", tmp_path / "d", episodes_per_task=0, tasks=[5])
    with pytest.raises(InvalidInput, match="valid: sampled, official"):
        record_demos("libero_10", tmp_path / "d", episodes_per_task=1, tasks=[5], starts="evaluation")
    assert not (tmp_path / "d").exists()
