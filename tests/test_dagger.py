"""`seal demos dagger`: the learned VLA's states labelled by the scripted expert, on the real simulator.

A tiny round (one task, one fresh start, 30 steps) checks that every stored label is what a fresh
`ScriptedExpert` says about that exact state, that a resume records nothing twice, and that
`seal train vla` trains on demonstrations and DAgger labels together.
"""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest

import seal.dagger as dagger
from seal.cli import main
from seal.errors import InvalidInput
from seal.policies.vla.locate import resolve_checkpoint

TASK = 5  # the book into the caddy: the shipped VLA picks the book up within 30 steps


@pytest.fixture(scope="module")
def labelled(tmp_path_factory):
    """One episode run in-process with the world's exact state captured at every labelled boundary."""
    snaps = []
    original = dagger.teacher_label

    def capturing(expert, obs):
        snaps.append(dagger._CACHE["world"].snapshot())
        return original(expert, obs)

    job = dagger.DaggerJob("libero_10", TASK, 0, 1, str(resolve_checkpoint("reason")), 0.5, "fast", 64, 30)
    dagger.teacher_label = capturing
    try:
        _, attempt, episode, rows = dagger.run_dagger_episode(job)
    finally:
        dagger.teacher_label = original
    world = dagger._CACHE.pop("world")  # this module's now: a later collection's clean-up must not close it
    dagger.release_cached()
    yield attempt, episode, rows, snaps, world
    world.close()


def test_every_label_is_the_experts_answer_for_that_exact_state(labelled):
    from seal.policies.expert.policy import ScriptedExpert

    attempt, episode, rows, snaps, world = labelled
    assert attempt["frames"] == len(rows) == len(snaps) == episode.length == 6  # a boundary every 5 steps
    assert attempt["executed"]["vla"] + attempt["executed"]["expert"] == 6
    for i, (row, snap) in enumerate(zip(rows, snaps)):
        world.restore(snap)
        expert = ScriptedExpert.for_world(world)  # a new expert: nothing carried over from the rollout
        obs = world.observe(images=False, privileged_atoms=expert.privileged_atoms())
        reasoning = expert.reason(obs)
        assert row["reasoning"] == reasoning.text() and row["now"] == reasoning.now
        expert.begin(1)
        chunk = expert.act([obs], reasoning)[0]
        assert row["valid"] and not chunk.think
        # Up to the kinematics' staleness: after a step, MuJoCo's site positions (what the scene reads for the
        # end effector) are those of the last substep's start, ~0.5 mm behind; a restored world recomputes
        # them. The expert is a smooth controller, so its chunk moves by ~0.01 (action units).
        np.testing.assert_allclose(row["chunk"].reshape(16, 7), np.asarray(chunk.actions, np.float32), atol=0.03)
        assert row["think"] == (row["vla_now"] != row["now"])
        np.testing.assert_allclose(obs.state, episode.states[i], atol=1e-6)  # the stored state is that state


def test_a_round_resumes_without_recording_anything_twice_and_trains_beside_demos(tmp_path, capsys):
    out = tmp_path / "dagger"
    argv = ["demos", "dagger", "--tasks", str(TASK), "--episodes-per-task", "1", "--max-steps", "30",
            "--beta", "0.5", "--out", str(out)]
    assert main(argv) == 0
    first = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert first["recorded"] == 1 and first["frames"] == 6
    assert main(argv) == 0  # the same command again: everything is done
    again = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert again["recorded"] == 0 and again["skipped"] == 1
    records = [json.loads(line) for line in (out / "annotations/annotations.jsonl").read_text().splitlines()]
    assert len(records) == 1 and records[0]["frame_labels"] and records[0]["start"] == ["libero_10", TASK, 0]
    table = pq.read_table(out / "annotations" / records[0]["labels_path"])
    assert table.num_rows == 6 and table.column("chunk").type.list_size == 16 * 7
    assert main(argv[:-2] + ["--beta", "0.2", "--out", str(out)]) == 2  # other settings: refused, nothing lost
    assert "other settings" in capsys.readouterr().err
    assert main(["demos", "dagger-report", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["episodes"] == 1 and report["frames"] == 6 and report["teacher_checks"] == 1
    assert report["teacher_recovered"] + len(report["teacher_unrecovered"]) == 1

    # trains on it beside demonstrations (224-px synthetic ones; the cache resizes them), fine-tuning the shipped VLA
    from _annotate_data import make_v21

    from seal.annotate.backends import make_annotator
    from seal.annotate.pipeline import annotate_dataset

    from seal.sim.fast_assets import CACHE_VERSION

    run = tmp_path / "run"
    # demonstrations in another render model than the model and the rollouts: refused before any work
    make_v21(tmp_path / "stock", [40, 35])
    annotate_dataset(tmp_path / "stock", tmp_path / "stock_ann", make_annotator("offline"))
    assert main(["train", "vla", "--annotations", f"{tmp_path}/stock_ann", "--out", str(run), "--steps", "3",
                 "--init-from", "reason", "--no-bf16"]) == 2
    assert "learned from 'fast' pixels" in capsys.readouterr().err and not run.exists()
    make_v21(tmp_path / "demos", [40, 35, 45], meta={"render_mode": "fast", "fast_version": CACHE_VERSION})
    annotate_dataset(tmp_path / "demos", tmp_path / "demos_ann", make_annotator("offline"))
    assert main(["train", "vla", "--annotations", f"{tmp_path}/demos_ann,{out}/annotations", "--mix", "1,1",
                 "--out", str(run), "--steps", "3", "--batch", "8", "--eval-every", "100", "--holdout", "0.34",
                 "--init-from", "reason", "--instruction-dropout", "0.3", "--no-bf16"]) == 0
    manifest = json.loads((run / "checkpoint/manifest.json").read_text())
    assert manifest["init_from"] == "reason" and manifest["train_config"]["instruction_dropout"] == 0.3
    assert manifest["render"] == {"mode": "fast", "fast_version": CACHE_VERSION}  # what rollouts render in
    assert [s["share"] for s in manifest["sources"]] == [0.5, 0.5] and manifest["sources"][1]["usable_frames"] == 6


def test_bad_settings_are_refused_before_anything_is_written(tmp_path):
    with pytest.raises(InvalidInput, match="--beta"):
        dagger.collect_dagger("libero_10", tmp_path / "a", ckpt="reason", episodes_per_task=1, beta=1.5)
    with pytest.raises(InvalidInput, match="non-reasoning twin"):
        dagger.collect_dagger("libero_10", tmp_path / "b", ckpt="twin", episodes_per_task=1)
    assert not list(tmp_path.iterdir())


def test_on_policy_figures_count_boundaries_and_committed_subplans():
    from seal.policies.base import Reasoning

    plans = ("pick up the book", "place it in the caddy")

    def row(vla_now, done):
        now = next((p for p in plans if p not in done), "")
        return {"vla_now": vla_now, "now": now, "reasoning": Reasoning(plans, tuple(done), now).text()}

    rows = [row("pick up the book", []), row("pick up the book", []),  # right, then held on too long:
            row("pick up the book", [plans[0]]), row("place it in the caddy", [plans[0]])]
    figures = dagger.on_policy_figures(rows, final_done=())
    # 3 of 4 boundaries name the expert's next sub-plan; "pick" was done when the VLA moved on, "place" was not
    assert figures == {"subplan_accuracy": 0.75, "alignment": 0.5, "committed": 2}
    assert dagger.on_policy_figures(rows, final_done=plans)["alignment"] == 1.0


def test_the_teacher_check_lets_the_expert_finish_alone_from_a_reached_state(labelled):
    """From the last labelled state of the tiny rollout (the book not yet in the caddy), the clean
    expert alone solves the task: the teacher had a good answer there, not only a label."""
    _, _, rows, snaps, world = labelled
    result = dagger.teacher_recovers(world, snaps[-1], budget=400)
    assert result["recovered"] and result["now"] == rows[-1]["now"] and result["steps"] <= 25 + 400


def test_round_log_keeps_one_row_per_round_and_draws_them(tmp_path):
    from seal.benchmarks.vla import log_round

    figures = {"ckpt": "x", "rollouts": [{}] * 20, "rollout_success": 0.1, "onpolicy_subplan_accuracy": 0.5,
               "onpolicy_alignment": 0.3}
    log = tmp_path / "rounds.jsonl"
    log_round(log, "0", figures)
    log_round(log, "1", figures | {"rollout_success": 0.2})
    png = log_round(log, "1", figures | {"rollout_success": 0.35})  # measured again: replaces round 1
    rows = [json.loads(line) for line in log.read_text().splitlines()]
    assert [(r["round"], r["rollout_success"], r["episodes"]) for r in rows] == [("0", 0.1, 20), ("1", 0.35, 20)]
    assert png == log.with_suffix(".png") and png.stat().st_size > 10_000


@pytest.mark.parametrize("runner", ["seal.demos:_run_parallel", "seal.dagger:collect_dagger"])
def test_recording_workers_leave_ctrl_c_to_the_parent(runner):
    """Both recorders start their spawned workers with SIGINT ignored (the parent stops the pool), so
    an interrupt prints one line, not a traceback per worker."""
    import importlib
    import inspect

    module, name = runner.split(":")
    assert "initializer=ignore_interrupts" in inspect.getsource(getattr(importlib.import_module(module), name))
    import multiprocessing
    import signal

    from seal.sim.pool import ignore_interrupts

    with multiprocessing.get_context("spawn").Pool(1, initializer=ignore_interrupts) as pool:
        assert pool.apply(signal.getsignal, (signal.SIGINT,)) == signal.SIG_IGN
