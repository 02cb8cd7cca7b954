"""V-GPS value learning: transitions from demonstrations, IQL learning, resume, scorer, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
from _annotate_data import make_v21, synthetic_episode

from seal.cli import main
from seal.errors import InvalidInput

import torch  # noqa: E402  (a test extra: a missing torch is a broken install, not a skip)

from seal.train.pipeline import split_episodes  # noqa: E402
from seal.train.transitions import Transitions, episode_transitions  # noqa: E402
from seal.train.vgps import IQLConfig, train_value  # noqa: E402
from seal.value.vgps import VGPSScorer, goal_tokens  # noqa: E402


def test_transitions_reward_the_chunk_that_reaches_each_goal():
    ep = synthetic_episode(40, seed=0)  # four sub-plans, critical frames spread over the episode
    ep.meta["success"] = True
    tr = episode_transitions(ep, "both")
    task = [i for i, g in enumerate(tr.goal) if g == ep.instruction]
    assert len(task) == 8 and tr.reward[task].tolist() == [0] * 7 + [1]  # 40 steps = 8 chunks of 5
    assert tr.to_goal[task].tolist() == [8, 7, 6, 5, 4, 3, 2, 1]
    # sub-plan rows follow the task's, one run of chunks per sub-plan (texts may repeat: split by reward)
    sub = [i for i in range(len(tr)) if i not in task]
    ends = [i for i in sub if tr.reward[i] == 1]
    assert len(ends) == len(ep.subplans) and all(tr.done[i] == 1 for i in ends)
    start, first_row = 0, sub[0]
    for text, frame, end in zip(ep.subplans, ep.critical_frames, ends):
        assert {tr.goal[i] for i in range(first_row, end + 1)} == {text}
        # the rewarded chunk ends with the action after which the sub-goal held (frame - 1)
        last_action = frame - 1
        chunk = tr.action[end].reshape(5, 7)
        assert np.allclose(chunk[(last_action - start) % 5], ep.actions[last_action])
        start, first_row = frame, end + 1
    ep.meta["success"] = False
    failed = episode_transitions(ep, "task")
    assert failed.reward.sum() == 0 and (failed.to_goal == -1).all()


def _bandit(n: int, seed: int) -> Transitions:
    """One-chunk episodes: reward 1 when the chunk moves along x the way the goal text says."""
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 255, (n, 56, 56, 3), dtype=np.uint8)
    state = rng.normal(size=(n, 8)).astype(np.float32)
    goals = rng.choice(["push the bowl left", "push the bowl right"], n).tolist()
    act = rng.uniform(-1, 1, (n, 35)).astype(np.float32)
    r = (np.sign(act[:, 0]) == np.where(["left" in g for g in goals], -1, 1)).astype(np.float32)
    return Transitions(img, state, act, goals, r, r.copy(), img, state, np.where(r > 0, 1, -1).astype(np.int32))


class _Obs:
    def __init__(self, state):
        self.agent, self.state = np.full((224, 224, 3), 90, np.uint8), state


def test_iql_learns_which_chunk_serves_the_goal(tmp_path):
    torch.manual_seed(0)
    train_value(_bandit(1000, 0), tmp_path, IQLConfig(steps=150, batch_size=32, hidden=64, lr=1e-3, save_every=150))
    scorer = VGPSScorer.load(tmp_path)
    chunks = np.zeros((2, 16, 7), np.float32)
    chunks[0, :, 0], chunks[1, :, 0] = -0.8, 0.8
    right = 0
    for i, goal in enumerate(["push the bowl left", "push the bowl right"] * 20):
        s = scorer.score(_Obs(np.random.default_rng(i).normal(size=8)), chunks, goal)
        right += (s[0] > s[1]) == ("left" in goal)
    assert right >= 36, f"{right}/40 rankings right"


def test_training_resumes_and_refuses_other_settings(tmp_path):
    data = _bandit(300, 1)
    train_value(data, tmp_path, IQLConfig(steps=10, batch_size=32, hidden=32, save_every=5, log_every=5))
    train_value(data, tmp_path, IQLConfig(steps=20, batch_size=32, hidden=32, save_every=5, log_every=5))
    steps = [json.loads(line)["step"] for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert steps == [5, 10, 15, 20]  # the second call went on from step 10
    with pytest.raises(InvalidInput, match="other settings or data"):
        train_value(data, tmp_path, IQLConfig(steps=30, batch_size=32, hidden=32, lr=1e-3))
    with pytest.raises(InvalidInput, match="other settings or data"):
        train_value(_bandit(300, 2), tmp_path, IQLConfig(steps=30, batch_size=32, hidden=32))


def test_goal_hashing_is_stable_and_splits_are_disjoint():
    assert goal_tokens("Pick up the BOOK") == goal_tokens("pick up the book")  # crc32, not Python's hash
    assert goal_tokens("") == [0]
    train, held = split_episodes(10, 0.2, seed=0)
    assert len(held) == 2 and not set(train) & set(held) and sorted(train + held) == list(range(10))
    with pytest.raises(InvalidInput, match="need at least 2"):
        split_episodes(1, 0.2, seed=0)
    with pytest.raises(InvalidInput, match=r"no V-GPS checkpoint"):
        VGPSScorer.load("/nonexistent/run")


def test_train_value_command_on_a_dataset(tmp_path, capsys):
    episodes = make_v21(tmp_path / "ds", [40, 35, 45])
    assert main(["train", "value", "--dataset", str(tmp_path / "ds"), "--out", str(tmp_path / "run"),
                 "--steps", "20", "--batch-size", "16", "--holdout", "0.34"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["last"]["step"] == 20
    # The held-out figures must be about the held-out episode, computed from the saved checkpoint.
    # Its transitions, built here independently from the source episodes, fix every denominator.
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    (held,) = summary["heldout_episodes"]
    assert sorted(summary["train_episodes"] + [held]) == [0, 1, 2]
    for ep in episodes:
        ep.meta["success"] = True  # what make_v21 records; the task goal is reached on the last chunk
    held_tr = episode_transitions(episodes[held], "both")
    train_tr = [episode_transitions(episodes[i], "both") for i in summary["train_episodes"]]
    assert out["heldout"]["transitions"] == len(held_tr) != out["train_fit"]["transitions"]
    assert out["train_fit"]["transitions"] == out["train_transitions"] == sum(len(t) for t in train_tr)
    near = int(((held_tr.to_goal >= 1) & (held_tr.to_goal <= 2)).sum())  # chunks 1-2 before their goal
    assert near >= 5  # five goals (task + four sub-plans), each reached
    acc = out["heldout"]["goal_accuracy"]
    assert any(abs(acc - round(j / near, 3)) < 1e-9 for j in range(near + 1)), (acc, near)  # a count / near
    assert -1 <= out["heldout"]["return_spearman"] <= 1
    nets_q = summary["heldout"]
    assert nets_q == out["heldout"]  # what was printed is what was saved
    summary = json.loads((tmp_path / "run/summary.json").read_text())
    assert len(summary["heldout_episodes"]) == 1 and len(summary["train_episodes"]) == 2
    assert (tmp_path / "run/checkpoint.pt").is_file()


def test_a_shipped_q_function_loads_by_name_and_a_damaged_run_never_ships(tmp_path, monkeypatch, capsys):
    import seal.value
    from seal.value import DEFAULT_SHIPPED, VALUE_CHECKPOINT, value_directory
    from seal.value.ship import ship

    make_v21(tmp_path / "ds", [40, 35, 45])
    run = tmp_path / "run"
    assert main(["train", "value", "--dataset", str(tmp_path / "ds"), "--out", str(run), "--steps", "10",
                 "--batch-size", "16", "--holdout", "0.34"]) == 0
    capsys.readouterr()
    root = tmp_path / "checkpoints"
    monkeypatch.setattr(seal.value, "SHIPPED_DIR", root)
    with pytest.raises(InvalidInput, match=f"no shipped V-GPS checkpoint '{DEFAULT_SHIPPED}'.*shipped: none"):
        value_directory("")
    target = ship(run, DEFAULT_SHIPPED, root=root, note="a test")
    # '' and the name both find it; its digest is the run's, so stores name both the same way
    assert value_directory("") == value_directory(DEFAULT_SHIPPED) == target
    assert VALUE_CHECKPOINT.digest(target) == VALUE_CHECKPOINT.digest(run)
    manifest = json.loads((target / "manifest.json").read_text())
    summary = json.loads((run / "summary.json").read_text())
    assert manifest["shipped"]["note"] == "a test" and manifest["training"]["heldout"] == summary["heldout"]
    assert VGPSScorer.load("").image_size == VGPSScorer.load(run).image_size
    with pytest.raises(InvalidInput, match="holds a shipped Q-function already"):
        ship(run, DEFAULT_SHIPPED, root=root)
    # one flipped byte in the run: refused before anything is copied
    weights = run / "value.safetensors"
    raw = bytearray(weights.read_bytes())
    raw[-1] ^= 1
    weights.write_bytes(bytes(raw))
    with pytest.raises(InvalidInput, match="manifest"):
        ship(run, "other", root=root)
    assert sorted(p.name for p in root.iterdir()) == [DEFAULT_SHIPPED]


def test_the_shipped_q_function_loads_on_a_fresh_clone_and_scores_the_policy_view():
    """What twin + V-GPS runs when no checkpoint is named: checked against its manifest, trained on
    the 64-px views the VLAs see, scoring K chunks to K finite numbers."""
    from seal.value import DEFAULT_SHIPPED, value_directory

    path = value_directory("")
    assert path.name == DEFAULT_SHIPPED
    manifest = json.loads((path / "manifest.json").read_text())
    assert manifest["training"]["heldout"]["transitions"] > 0 and manifest["shipped"]["name"] == DEFAULT_SHIPPED
    scorer = VGPSScorer.load("")
    assert scorer.image_size == 64
    from seal.steer.method import parse_methods

    (spec,) = parse_methods("value:policy=vla:policy_ckpt=twin:k=10")  # what generalization.sh runs
    assert spec.label.startswith(f"value[ckpt={DEFAULT_SHIPPED},")
    obs = _Obs(np.zeros(8))
    obs.agent = np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    scores = scorer.score(obs, np.random.default_rng(1).uniform(-1, 1, (10, 16, 7)).astype(np.float32),
                          "put both the alphabet soup and the tomato sauce in the basket")
    assert scores.shape == (10,) and np.isfinite(scores).all() and np.ptp(scores) > 0


def test_value_function_from_a_64px_dataset_scores_the_policy_view(tmp_path):
    """A VLA recorded at 64 px: the value function trains on those frames (area-resized to 56) and
    asks the loop for 64-px views, so the policy's own renders serve it."""
    from PIL import Image

    from seal.datasets.lerobot import LeRobotWriter
    from seal.sim.observation import Observation
    from seal.steer.scoring import scoring_view
    from seal.value.inputs import downsample

    def small(images):
        return np.stack([np.asarray(Image.fromarray(im).resize((64, 64), Image.BOX)) for im in images])

    episodes = [synthetic_episode(T, seed=i) for i, T in enumerate([30, 25])]
    for ep in episodes:
        ep.agent_images, ep.wrist_images = small(ep.agent_images), small(ep.wrist_images)
    with LeRobotWriter(tmp_path / "ds", fps=20, image_size=64) as w:
        for ep in episodes:
            w.add(ep)
    frame = episodes[0].agent_images[:1]
    expected = np.asarray(Image.fromarray(frame[0]).resize((56, 56), Image.BOX))
    assert np.array_equal(downsample(frame)[0], expected)
    assert downsample(np.zeros((2, 224, 224, 3), np.uint8)).shape == (2, 56, 56, 3)  # openpi's view: pooled
    with pytest.raises(InvalidInput, match="square images"):
        downsample(np.zeros((1, 64, 48, 3), np.uint8))

    assert main(["train", "value", "--dataset", str(tmp_path / "ds"), "--out", str(tmp_path / "run"),
                 "--steps", "4", "--batch-size", "8", "--holdout", "0"]) == 0
    assert json.loads((tmp_path / "run/summary.json").read_text())["image_size"] == 64
    scorer = VGPSScorer.load(tmp_path / "run")
    assert scorer.image_size == 64
    obs64 = Observation(state=np.zeros(8, np.float32), prompt="p", agent=episodes[0].agent_images[0])
    assert scorer.score(obs64, np.zeros((3, 5, 7), np.float32), "put the bowl on the plate").shape == (3,)

    asked = []

    def render(images):  # the loop's one more render of the same state, at the size asked for
        asked.append(images)
        return np.zeros((images, images, 3), np.uint8)

    assert scoring_view(scorer, obs64, render) is obs64 and asked == []  # the policy's render serves
    obs224 = Observation(state=np.zeros(8, np.float32), prompt="p", agent=np.zeros((224, 224, 3), np.uint8))
    assert scoring_view(scorer, obs224, render).agent.shape == (64, 64, 3) and asked == [64]


@pytest.mark.parametrize("field, value, message", [
    ("steps", -1, "steps must be an integer >= 0"),
    ("batch_size", 0, "batch_size must be an integer >= 1"),
    ("lr", float("nan"), "lr must be a finite number > 0"),
    ("gamma", 1.0, r"gamma must be in \[0, 1\)"),
    ("expectile", 0.0, r"expectile must be in \(0, 1\)"),
    ("polyak", 0.0, r"polyak must be in \(0, 1\]"),
    ("hidden", 2.5, "hidden must be an integer >= 1"),
])
def test_iql_config_refuses_bad_values_with_the_field_named(field, value, message):
    with pytest.raises(InvalidInput, match=message):
        IQLConfig(**{field: value})
    IQLConfig()  # the defaults pass


def _rollout_collection(root, solved: list[bool], px: int = 64):
    """A `seal demos dagger`-shaped collection without the simulator: synthetic ``px``-px frames, the
    expert's `now` label advancing through the plans, the executed actions of every boundary."""
    import dataclasses

    from _annotate_data import PLANS

    from seal.annotate.pipeline import ANNOTATIONS, CHUNK_SIZE, LABELS_PATH
    from seal.dagger import _write_labels
    from seal.datasets import LeRobotWriter
    from seal.policies.base import Reasoning

    episodes, rows_of = [], []
    with LeRobotWriter(root / "dataset", fps=4, image_size=px) as w:
        for i, ok in enumerate(solved):
            ep = synthetic_episode(8, seed=i)
            small = ep.agent_images
            if px == 64:  # 56-px synthetic frames padded to 64
                small = np.ascontiguousarray(np.pad(small[:, ::4, ::4], ((0, 0), (0, 8), (0, 8), (0, 0))))
            ep = dataclasses.replace(ep, agent_images=small, wrist_images=255 - small,
                                     critical_frames=[-1] * len(PLANS),
                                     meta=ep.meta | {"success": ok, "dagger": {"ckpt": "test"}})
            # the expert's next sub-plan per boundary: plan 0 for 3 boundaries, plan 1 for 2, a frame it could
            # not label, then plan 1 again; an unsolved episode stops moving at its last boundary
            at = [0, 0, 0, 1, 1, None, 1, 3 if ok else 1]  # plans 1 and 3 share a text: the done list tells them apart
            now = [Reasoning(tuple(PLANS), tuple(PLANS[:k]), PLANS[k]).text() if k is not None else "?" for k in at]
            rows = [{"reasoning": n, "now": n, "vla_reasoning": n, "vla_now": n, "think": False, "valid": n != "?",
                     "why": "", "step": 5 * j, "chunk": np.zeros(16 * 7, np.float32), "chunk_steps": 16,
                     "executed": [np.full(7, 0.1 * j, np.float32)] * (5 if ok or j < 7 else 0)}
                    for j, n in enumerate(now)]
            index = w.add(ep)
            ann = root / "annotations"
            ann.mkdir(exist_ok=True)
            _write_labels(ann, index, ep, rows, LABELS_PATH, CHUNK_SIZE, ANNOTATIONS)
            episodes.append(ep)
            rows_of.append(rows)
    return episodes, rows_of


def test_rollout_transitions_reward_reached_goals_and_keep_failures(tmp_path):
    from _annotate_data import PLANS

    from seal.train.transitions import rollout_transitions

    episodes, _ = _rollout_collection(tmp_path / "coll", [True, False])
    solved = rollout_transitions(tmp_path / "coll", "both", [0])
    task = [i for i, g in enumerate(solved.goal) if g == episodes[0].instruction]
    assert solved.reward[task].tolist() == [0] * 7 + [1] and solved.to_goal[task].tolist() == list(range(8, 0, -1))
    # the executed chunk of boundary j (actions 0.1 * j), and the next boundary's frame after it
    assert np.allclose(solved.action[task][3], 0.3) and (solved.next_state[task][3] == episodes[0].states[4]).all()
    sub = [(g, r) for g, r in zip(solved.goal, solved.reward) if g != episodes[0].instruction]
    # plan 0 reached when the expert moves on to plan 1; plan 1 cut by the unlabelled frame (not reached),
    # picked up again and reached when the expert names the last plan; the last plan reached with the task
    assert sub == [(PLANS[0], 0), (PLANS[0], 0), (PLANS[0], 1), (PLANS[1], 0), (PLANS[1], 0),
                   (PLANS[1], 1), (PLANS[-1], 1)]
    failed = rollout_transitions(tmp_path / "coll", "task", [1])
    # the failed episode's last boundary executed nothing (the VLA declared the task done): no transition
    assert len(failed) == 7 and failed.reward.sum() == 0 and (failed.to_goal == -1).all()


def test_value_trains_on_demonstrations_and_rollouts_and_refuses_old_collections(tmp_path, capsys):
    import pyarrow.parquet as pq

    make_v21(tmp_path / "demos", [40, 35, 45])  # 224-px demonstrations: rollouts of the same view size
    _rollout_collection(tmp_path / "coll", [True, False, True, False, True], px=224)
    argv = ["train", "value", "--dataset", str(tmp_path / "demos"), "--rollouts", str(tmp_path / "coll"),
            "--out", str(tmp_path / "run"), "--steps", "20", "--batch", "16", "--holdout", "0.4"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["rollout_transitions"] > 0 and out["heldout_rollouts"]["transitions"] > 0
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    (split,) = summary["rollouts"].values()
    assert sorted(split["train_episodes"] + split["heldout_episodes"]) == [0, 1, 2, 3, 4]
    # scored on rollouts (here the same collection): per run and goal kind, on the collection's transitions
    assert main(["bench", "value", "--ckpt", str(tmp_path / "run"), "--data", str(tmp_path / "coll"), "--k", "4"]) == 0
    scored = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["rollouts"]
    assert scored["episodes_solved"] == 3 and scored["task_transitions"] == 3 * 8 + 2 * 7
    assert set(scored[str(tmp_path / "run")]) == {"task", "subplan"}
    assert scored[str(tmp_path / "run")]["task"]["transitions"] == 38
    # a collection from before the executed actions were kept: refused, naming what to do
    labels = next((tmp_path / "coll" / "annotations").rglob("*.parquet"))
    pq.write_table(pq.read_table(labels).drop_columns(["executed"]), labels)
    assert main(argv[:-8] + ["--out", str(tmp_path / "run2"), "--steps", "5", "--holdout", "0.4"]) == 2
    assert "before DAgger kept the executed actions" in capsys.readouterr().err
    _rollout_collection(tmp_path / "small", [True, False])  # 64-px views beside 224-px demonstrations: refused
    assert main(argv[:4] + ["--rollouts", str(tmp_path / "small"), "--out", str(tmp_path / "run4")]) == 2
    assert "64-px views, the demonstrations 224-px" in capsys.readouterr().err
    assert main(["train", "value", "--dataset", str(tmp_path / "demos"), "--rollouts", str(tmp_path / "nope"),
                 "--out", str(tmp_path / "run3")]) == 2
    assert "not a `seal demos dagger` collection" in capsys.readouterr().err
