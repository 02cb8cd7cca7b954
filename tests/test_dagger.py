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

    def capturing(expert, obs, world=None):
        snaps.append(dagger._CACHE["world"].snapshot())
        return original(expert, obs, world)

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
        np.testing.assert_allclose(obs.state, episode.states[i], atol=1e-6)  # the stored state is that state
        reasoning = expert.reason(obs)
        assert row["reasoning"] == reasoning.text() and row["now"] == reasoning.now
        expert.begin(1)
        chunk = expert.act([obs], reasoning)[0]
        assert row["valid"] and not chunk.think
        label = row["chunk"].reshape(16, 7)
        # Up to the kinematics' staleness: after a step, MuJoCo's site positions (what the scene reads for the
        # end effector) are those of the last substep's start, ~0.5 mm behind; a restored world recomputes
        # them. The expert is a smooth controller, so its chunk moves by ~0.01 (action units).
        np.testing.assert_allclose(label[:5], np.asarray(chunk.actions, np.float32)[:5], atol=0.03)
        assert row["chunk_steps"] == 16  # no episode end within 16 steps here
        if i in (0, 3):
            # closed loop: the rest of the label is what the expert does when it goes on from there,
            # planning afresh every 5 steps (as in a recorded demonstration), not its one-shot tail
            for block in (1, 2):
                for action in label[5 * (block - 1):5 * block]:
                    world.step(action)
                obs = world.observe(images=False, privileged_atoms=expert.privileged_atoms())
                replanned = expert.act([obs], reasoning)[0]
                assert not replanned.think
                np.testing.assert_allclose(label[5 * block:5 * block + 5], replanned.actions[:5], atol=0.03)
        assert row["think"] == (row["vla_now"] != row["now"])


def test_executed_actions_lead_from_each_stored_state_to_the_next(labelled):
    """The transitions offline RL reads: a boundary's executed actions, replayed from its exact state,
    give the next boundary's stored state (the VLA's chunks and the expert's, whichever ran)."""
    attempt, episode, rows, snaps, world = labelled
    assert [len(r["executed"]) for r in rows] == [5] * 6
    for i in range(len(rows) - 1):
        world.restore(snaps[i])
        for action in rows[i]["executed"]:
            world.step(action)
        np.testing.assert_allclose(world.observe(images=False).state, episode.states[i + 1], atol=1e-6)
    # the chunk that ran is the expert's label where the mixture picked the expert, else the VLA's own
    assert sum(np.allclose(np.stack(r["executed"]), r["chunk"].reshape(16, 7)[:5]) for r in rows) >= \
        attempt["executed"]["expert"]


def test_labels_of_older_collections_train_only_their_executed_prefix(tmp_path):
    """Collections from before closed-loop labels stored the expert's one-shot extrapolation, whose
    tail is not what the expert executes: only the first ACTION_HORIZON steps count there."""
    import pyarrow as pa

    from seal.policies.base import ACTION_HORIZON

    table = pa.table({"reasoning": ["a"], "vla_reasoning": ["a"], "now": ["x"], "think": [False], "valid": [True],
                      "chunk": pa.array([[0.0] * 112], pa.list_(pa.float32(), 112))})
    pq.write_table(table, tmp_path / "old.parquet")
    old = dagger.read_frame_labels(tmp_path, {"labels_path": "old.parquet"})
    assert old["chunk_steps"].tolist() == [ACTION_HORIZON] and old["executed"] is None  # unknown, not empty
    pq.write_table(table.append_column("chunk_steps", pa.array([11], pa.int64())), tmp_path / "new.parquet")
    assert dagger.read_frame_labels(tmp_path, {"labels_path": "new.parquet"})["chunk_steps"].tolist() == [11]


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
    labels = dagger.read_frame_labels(out / "annotations", records[0])
    assert [a.shape for a in labels["executed"]] == [(5, 7)] * 6
    assert main(argv[:-2] + ["--beta", "0.2", "--out", str(out)]) == 2  # other settings: refused, nothing lost
    assert "other settings" in capsys.readouterr().err
    assert main(["demos", "dagger-report", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["episodes"] == 1 and report["frames"] == 6 and report["teacher_checks"] == 1
    assert report["teacher_recovered"] + len(report["teacher_unrecovered"]) == 1
    # the episode's metadata gives the rollout's length, not where the teacher check left the world
    (meta,) = [json.loads(line) for line in (out / "dataset/meta/episodes.jsonl").read_text().splitlines()]
    (logged,) = [json.loads(line) for line in (out / "attempts.jsonl").read_text().splitlines()]
    assert meta["meta"]["steps"] == logged["steps"] == 30

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
    with pytest.raises(InvalidInput, match="non-reasoning twin: it writes no sub-plans"):
        dagger.collect_dagger("libero_10", tmp_path / "b", ckpt="twin", episodes_per_task=1,
                              verifier_cases=tmp_path / "cases")
    assert not list(tmp_path.iterdir())


def test_the_twin_rolls_out_with_expert_labels_and_never_thinks():
    """The pi0 twin's own states (DAgger for the baseline, and its chunks for offline RL): the expert's
    labels as for the reasoning VLA, its own text the instruction, no think label."""
    job = dagger.DaggerJob("libero_10", TASK, 0, 1, str(resolve_checkpoint("twin")), 0.0, "fast", 64, 15)
    _, attempt, episode, rows = dagger.run_dagger_episode(job)
    dagger.release_cached()
    assert attempt["frames"] == len(rows) == 3 and attempt["executed"] == {"vla": 3, "expert": 0}
    assert all(r["valid"] and not r["think"] and r["vla_now"] == episode.instruction for r in rows)
    assert all(r["now"] == "pick up the book" for r in rows) and [len(r["executed"]) for r in rows] == [5, 5, 5]


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
    # a twin's round has no sub-plan figures: drawn as a gap; the plot is redrawn from the log alone
    log_round(log, "twin", {"ckpt": "t", "rollouts": [{}] * 20, "rollout_success": 0.15})
    png.unlink()
    from seal.cli import main

    assert main(["bench", "vla", "--round-log", str(log), "--redraw"]) == 0
    assert png.stat().st_size > 10_000
    assert main(["bench", "vla", "--round-log", str(tmp_path / "none.jsonl"), "--redraw"]) == 2
    # some rounds, in the order asked, to another file; a round the log lacks is refused, naming the ones it has
    from seal.benchmarks.vla import redraw_rounds

    picked = redraw_rounds(str(log), ["twin", "0"], str(tmp_path / "two.png"))
    assert picked["rounds"] == 2 and (tmp_path / "two.png").stat().st_size > 10_000
    with pytest.raises(InvalidInput, match="'7' is not in .*'0'; '1'; 'twin'"):
        redraw_rounds(str(log), ["7"])


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


# ---- verification cases from the same rollouts (`--verifier-cases`, issue 32) ----------------------------------
CASES_TASK, CASES_STEPS = 0, 95  # soup and sauce into the basket: by step 90 the VLA has picked and placed the soup


@pytest.fixture(scope="module")
def with_cases():
    """The same DAgger episode run without and with verification cases, the world's exact state captured
    at every case (the held-versus-released one included, taken after the rollout)."""
    ckpt = str(resolve_checkpoint("reason_r0"))  # the first shipped VLA: the rollout the tests below describe
    plain = dagger.run_dagger_episode(dagger.DaggerJob("libero_10", CASES_TASK, 0, 1, ckpt, 0.5, "fast", 64, CASES_STEPS))
    snaps = []
    original = dagger.VerifierCaseTaker._case

    def capturing(self, request, **kw):
        snaps.append(self.world.snapshot())
        return original(self, request, **kw)

    dagger.VerifierCaseTaker._case = capturing
    try:
        job = dagger.DaggerJob("libero_10", CASES_TASK, 0, 1, ckpt, 0.5, "fast", 64, CASES_STEPS, verifier_cases=True)
        taken = dagger.run_dagger_episode(job)
    finally:
        dagger.VerifierCaseTaker._case = original
    world = dagger._CACHE.pop("world")
    dagger.release_cached()
    yield plain, taken, snaps, world
    world.close()


def test_taking_verifier_cases_leaves_the_rollout_and_its_dagger_data_unchanged(with_cases):
    (_, a0, e0, r0), (_, a1, e1, r1), _, _ = with_cases
    cases = a1.pop(dagger.CASES_KEY)
    assert cases["rows"] and dagger.CASES_KEY not in a0
    assert a0 == a1 and e0.meta == e1.meta and len(r0) == len(r1)
    for x, y in zip(r0, r1):
        assert x.keys() == y.keys() and all(np.array_equal(x[k], y[k]) for k in x)
    for name in ("agent_images", "wrist_images", "states", "actions"):
        assert np.array_equal(getattr(e0, name), getattr(e1, name)), name
    a1[dagger.CASES_KEY] = cases


def test_every_verifier_case_label_is_the_oracles_at_that_exact_state(with_cases):
    from seal.verify import dataset as ds
    from seal.verify.base import VerifyRequest
    from seal.verify.oracle import OracleVerifier

    _, (_, attempt, _, _), snaps, world = with_cases
    rows = attempt[dagger.CASES_KEY]["rows"]
    assert len(rows) == len(snaps) and attempt[dagger.CASES_KEY]["unknown"] == 0
    by = {r["ended_by"]: r for r in rows}
    # what this rollout of the shipped VLA does: picks the soup (a think case), places it (think), and the
    # place's last closed-gripper boundary, the soup still held above the basket, is the paired hard negative
    assert [(r["ended_by"], r["kind"], r["label"]) for r in rows] == [
        ("think", "pick", True), ("think", "place", True), ("before_release", "place", False)]
    pair, placed = by["before_release"], rows[1]
    assert pair["subplan"] == placed["subplan"] and pair["first_agent"] == placed["first_agent"]
    assert pair["final_wrist"] != placed["final_wrist"] and pair["steps"] < placed["steps"]
    for row, snap in zip(rows, snaps):
        assert row["init_source"] == "fresh-train" and row["policy"] == "vla" and row["init_seed"] == attempt["start_seed"]
        # the label, recomputed from the world restored to that state by a fresh oracle
        world.restore(snap)
        oracle = OracleVerifier()
        scene = world.scene_state()
        objects = sorted(set(scene.bodies) | set(scene.sites))
        req = VerifyRequest(subplan=row["subplan"], instruction=row["instruction"], plans=tuple(row["plans"]),
                            index=None if row["subplan_index"] < 0 else row["subplan_index"],
                            goal_atoms=tuple(row["atoms"]) if row["kind"] == "task" else ())
        req.scene = world.scene_state(oracle.atoms_needed(req, objects))
        verdict = oracle.judge(req)
        assert verdict.success is row["label"] and verdict.extra["atoms"] == row["atoms"], row["case_id"]
        # ...and from the stored case, as `seal bench verifier` reads it
        case = ds.Case(dict(row), tuple(ds.decode_png(row[c]) for c in ds.IMAGE_COLUMNS))
        assert OracleVerifier().judge(ds.to_request(case)).success is row["label"]
        # the final views are that state's 224-px views, pixel for pixel (the pair's, rendered after the rollout, too)
        assert case.images[1].shape == (224, 224, 3)
        assert np.array_equal(case.images[1], world.observe(images=True).agent)


def test_task_level_cases_are_labelled_on_the_tasks_goal(tmp_path):
    """A task-level case (the VLA's 'the task is complete', or where LIBERO's check first holds): the
    instruction judged on the task's goal atoms, with the episode's first view as 'before'."""
    from seal.sim.world import LiberoWorld
    from seal.policies.base import Reasoning
    from seal.verify import dataset as ds
    from seal.verify.oracle import OracleVerifier

    world = LiberoWorld(("libero_10", 5), render_mode="fast")
    try:
        world.reset_sampled(dagger.dagger_seed(world.task.key, 1, 0))
        job = dagger.DaggerJob("libero_10", 5, 0, 1, "x", 0.0, "fast", 64, verifier_cases=True)
        taker = dagger.VerifierCaseTaker(world, job, 7)
        plans = ("pick up the book", "place it in the back compartment of the caddy")
        taker.begin(Reasoning(plans, (), plans[0]))
        taker.declared_done(Reasoning(plans, plans, ""))  # the VLA says done at once: the book is not in the caddy
        out = taker.finish()
    finally:
        world.close()
    (row,) = out["rows"]
    assert row["kind"] == "task" and row["ended_by"] == "vla_done" and row["subplan"] == row["instruction"]
    assert row["atoms"] == [str(a) for a in world.task.goal_atoms()] and row["label"] is False
    assert row["first_agent"] == row["final_agent"]  # nothing moved: the first view is the final one
    case = ds.Case(row, tuple(ds.decode_png(row[c]) for c in ds.IMAGE_COLUMNS))
    assert ds.to_request(case).task_level and OracleVerifier().judge(ds.to_request(case)).success is False


def test_a_round_writes_verifier_cases_once_and_they_train_beside_others(tmp_path, capsys):
    from _verifier_cases import write_cases

    from seal.benchmarks.verifier import score
    from seal.policies.vla.locate import checkpoint_digest
    from seal.verify import dataset as ds
    from seal.verify.oracle import OracleVerifier

    out, cases = tmp_path / "dagger", tmp_path / "cases"
    argv = ["demos", "dagger", "--tasks", str(TASK), "--episodes-per-task", "1", "--max-steps", "45",
            "--beta", "0.5", "--no-teacher-check", "--verifier-cases", str(cases), "--out", str(out)]
    assert main(argv) == 0
    first = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert first["recorded"] == 1 and first["verifier_cases"] == 1  # the book picked up at step 40
    shard = cases / "data" / ds.shard_name("libero_10", TASK, 0)
    stamp = shard.stat().st_mtime_ns
    assert "verifier_cases" not in (out / "attempts.jsonl").read_text()  # the DAgger log is as without cases
    assert main(argv) == 0  # again: nothing to do, nothing written twice
    again = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert again["skipped"] == 1 and again["verifier_cases"] == 0 and shard.stat().st_mtime_ns == stamp
    assert len(ds.shard_paths(cases)) == 1 and ds.read_cases(cases).num_rows == 1
    info = ds.read_info(cases)
    assert "task" in info["kinds"]
    collection = info["collection"]
    assert collection["policy"] == "vla" and collection["vla_ckpt_digest"] == checkpoint_digest("reason")
    assert collection["counts"]["cases"] == 1 and collection["render_mode"] == "fast"
    # another collection's settings into the same cases directory: refused before anything runs
    other = argv[:-4] + ["--round", "2", "--verifier-cases", str(cases), "--out", str(tmp_path / "r2")]
    assert main(other) == 2 and "other settings" in capsys.readouterr().err and not (tmp_path / "r2").exists()
    assert score(OracleVerifier(), cases)["accuracy"] == 1.0  # `seal bench verifier` reads them

    # `seal train verifier --data A,B`: these cases beside cases in the older layout
    synthetic = write_cases(tmp_path / "synthetic", 24, tasks=("libero_10/0",), inits=6)
    run = tmp_path / "verifier"
    assert main(["train", "verifier", "--data", f"{synthetic},{cases}", "--steps", "2", "--batch-size", "8",
                 "--image-size", "32", "--holdout-inits", "0", "--out", str(run)]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["step"] == 2 and summary["split"]["train"] == 25


def test_bench_labels_closed_loop_tails_follow_the_executed_actions(capsys):
    """`seal bench labels` on one expert episode: closed-loop tails are as close to what the expert
    executed as the first steps are; one-shot tails are several times further off."""
    assert main(["bench", "labels", "--tasks", "0", "--trials", "1"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["episodes"] == 1 and out["boundaries"] > 10
    one, closed = out["one_shot"], out["closed_loop"]
    assert closed["mse_executed_prefix"] == one["mse_executed_prefix"]  # the same first steps
    assert closed["mse_tail"] <= 2 * closed["mse_executed_prefix"] + 0.005
    assert one["mse_tail"] > 3 * closed["mse_tail"] and one["mse_tail"] > 0.1 * out["executed_action_var_arm"]
