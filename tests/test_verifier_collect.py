"""`seal verify collect` and `seal bench verifier-sweep` on the real simulator, kept tiny: LIBERO-10
task 5 (the book, two sub-plans), K=2, short episodes."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from seal.cli import main
from seal.collect import FRESH_SEED_OFFSET
from seal.errors import InvalidInput
from seal.sim import generate
from seal.sim.suites import get_task
from seal.verify import dataset as ds

TASK = get_task("libero_10", 5)
COLLECT = ["verify", "collect", "--suite", "libero_10", "--tasks", "5", "--k", "2", "--inits-per-task", "1",
           "--max-steps", "60", "--workers", "1"]


def _json(capsys) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_collect_keeps_what_the_verifier_saw_with_the_oracle_label_and_resumes(tmp_path, capsys):
    out = tmp_path / "cases"
    assert main([*COLLECT, "--per-task", "3", "--out", str(out)]) == 0
    first = _json(capsys)
    assert first["episodes_run"] >= 1 and first["cases"] == 3
    table = ds.read_cases(out)
    rows = table.to_pylist()
    assert len(rows) == 3
    official = {tuple(s) for s in np.round(TASK.init_states(), 6)}
    states = np.load(next((out / "init_states").glob("*.npz")))
    assert not {tuple(s) for s in np.round(states["states"], 6)} & official  # fresh, not LIBERO's evaluation starts
    assert states["seeds"].min() >= generate.task_seed(TASK) + FRESH_SEED_OFFSET["fresh-train"]
    for r in rows:
        assert r["task"] == "libero_10/5" and r["init_source"] == "fresh-train" and r["init_seed"] in states["seeds"]
        assert r["label"] == all(r["atom_values"]) and r["atoms"]
        assert r["kind"] == ("pick" if r["atoms"][0].startswith("Held") else "place")  # the oracle's pick check
        assert r["subplan"] in r["plans"] and r["instruction"] == TASK.instruction
        assert r["ended_by"] in ("think", "budget", "step_limit")
        first_view, final_view, wrist = (ds.decode_png(r[c]) for c in ds.IMAGE_COLUMNS)
        assert first_view.shape == final_view.shape == wrist.shape == (224, 224, 3)
        assert not np.array_equal(first_view, final_view)  # the arm moved between the two front views
    rounds = Counter((r["episode"], r["subplan_number"], r["round"]) for r in rows)
    assert max(rounds.values()) == 2  # whole rounds: both candidates of a round were judged
    info = json.loads((out / "info.json").read_text())
    assert info["collection"]["counts"]["libero_10/5"]["success"] + info["collection"]["counts"]["libero_10/5"][
        "failure"] == 3
    assert info["collection"]["render_mode"] == "stock"  # the scripted policy's pixels: stock MuJoCo
    shards = ds.shard_paths(out)

    assert main([*COLLECT, "--per-task", "3", "--out", str(out)]) == 0  # nothing left to do
    assert _json(capsys)["episodes_run"] == 0 and ds.shard_paths(out) == shards
    assert main([*COLLECT, "--per-task", "5", "--out", str(out), "--knobs", "clean"]) == 2
    assert "other settings" in capsys.readouterr().err


def test_resume_counts_shards_and_balance_keeps_classes_even(tmp_path):
    from _verifier_cases import make_row

    from seal.collect import CollectOptions, _done, _keep, existing

    out = tmp_path / "cases"
    ds.write_shard(out, ds.shard_name("libero_10", 5, 0), [make_row(i, task="libero_10/5", label=i < 3)
                                                           for i in range(4)])
    ds.write_shard(out, ds.shard_name("libero_10", 5, 1), [])  # an episode that kept nothing still counts
    ds.write_shard(out, ds.shard_name("libero_90", 12, 0), [make_row(9, task="libero_90/12", label=False)])
    (out / "data" / ".shard-libero_10-005-00002.parquet.tmp").write_bytes(b"torn")  # an interrupted write
    ds.write_info(out, {"collection": {}})
    have = existing(out)
    assert have["libero_10/5"] == {"episodes": {0, 1}, "success": 3, "failure": 1}
    assert have["libero_90/12"] == {"episodes": {0}, "success": 0, "failure": 1}
    opts = CollectOptions(suite="libero_10", tasks=[5], per_task=8, balance=True)
    rows = [{"label": bool(x)} for x in (1, 1, 0, 0, 0, 1, 0)]
    kept = _keep(rows, have["libero_10/5"], opts)
    assert [r["label"] for r in kept] == [True, False, False, False]  # successes capped at 4, failures fill up
    assert have["libero_10/5"]["success"] == 4 and have["libero_10/5"]["failure"] == 4 and _done(have["libero_10/5"], opts)
    plain = CollectOptions(suite="libero_10", tasks=[5], per_task=5)
    counts = {"success": 3, "failure": 1}
    assert len(_keep(rows, counts, plain)) == 1 and _done(counts, plain)


def test_noise_sweep_writes_rows_as_it_goes_resumes_and_plots(tmp_path, capsys):
    point = tmp_path / "learned.json"
    point.write_text(json.dumps({"verifier": "learned:run", "fp_rate": 0.05, "fn_rate": 0.3, "cases": 40}))
    args = ["bench", "verifier-sweep", "--suite", "libero_10", "--tasks", "5", "--trials", "1", "--fp", "0,1",
            "--fn", "0", "--k", "2", "--max-steps", "60", "--workers", "1", "--out", str(tmp_path / "sweep"),
            "--points", str(point)]
    assert main(args) == 0
    result = _json(capsys)
    assert result["episodes_run"] == 3  # the policy alone, and two grid cells
    rows = [json.loads(x) for x in (tmp_path / "sweep" / "results.jsonl").read_text().splitlines()]
    assert sorted(r["cell"] for r in rows) == ["base", "fp=0,fn=0", "fp=1,fn=0"]
    assert len({(r["init"], r["seed"]) for r in rows}) == 1  # every cell on the same start and seed
    assert set(result["grid"]) == {"fp=0,fn=0", "fp=1,fn=0"} and result["grid"]["fp=0,fn=0"]["episodes"] == 1
    md = (tmp_path / "sweep" / "sweep.md").read_text()
    assert "learned:run" in md and "| 0 |" in md and "(misaligned expert)" in md
    from seal.benchmarks.sweep import load_points, markdown, summarize

    vla_md = markdown(summarize(rows, (0.0, 1.0), (0.0,)), (0.0, 1.0), (0.0,), [], "vla")
    assert "(vla)" in vla_md and "misaligned" not in vla_md  # the table names the policy it ran
    shipped = tmp_path / "shipped.json"
    shipped.write_text(json.dumps({"verifier": "learned:/x/seal/verify/checkpoints/learned", "fp_rate": 0.1,
                                   "fn_rate": 0.05, "cases": 9}))
    assert [p["label"] for p in load_points(f"{point},{shipped}")] == ["learned:run", "learned"]
    assert (tmp_path / "sweep" / "sweep.png").stat().st_size > 10_000
    assert main(args) == 0
    assert _json(capsys)["episodes_run"] == 0  # resumed: nothing ran twice
    # a verifier measured outside the grid (one FP column, the star at FP 0.29) is inside the axes
    from seal.benchmarks.sweep import _edges, plot_limits

    lo, hi = plot_limits(_edges([0.0]), [0.29])
    assert lo <= 0.0 and hi > 0.29 and plot_limits(_edges([0.0, 0.4]), [])[1] > 0.6
    with pytest.raises(InvalidInput, match="rates"):
        from seal.benchmarks.sweep import _rates

        _rates("0,2", (), "--fp")


def test_a_task_that_yields_nothing_is_given_up_and_the_others_go_on(tmp_path, capsys, monkeypatch):
    """With --balance, a task that can never yield the missing class stops after --patience barren
    episodes instead of running --max-episodes; a task whose starts cannot be drawn is skipped."""
    out = tmp_path / "cases"
    # 10 steps: no candidate can pick the book, so failures fill their half and successes never come
    assert main([*COLLECT, "--per-task", "2", "--balance", "--max-steps", "10", "--patience", "2",
                 "--out", str(out)]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out.strip().splitlines()[-1])
    assert summary["episodes_run"] == 3 and summary["counts"]["libero_10/5"]["failure"] == 1
    assert "2 episodes in a row kept no case (still missing successes" in summary["tasks_given_up"]["libero_10/5"]
    assert "libero_10/5 given up" in captured.err

    import seal.collect as collect_module

    real = collect_module.fresh_init_states

    def refuse(task, *a, **k):
        if task.task_id == 5:
            raise InvalidInput(f"{task.key}: only 0 usable fresh init states in 420 draws")
        return real(task, *a, **k)

    monkeypatch.setattr(collect_module, "fresh_init_states", refuse)
    assert main(["verify", "collect", "--suite", "libero_10", "--tasks", "5,1", "--k", "2", "--inits-per-task", "1",
                 "--max-steps", "10", "--workers", "1", "--per-task", "1", "--out", str(tmp_path / "two")]) == 0
    summary = _json(capsys)
    assert "only 0 usable" in summary["tasks_given_up"]["libero_10/5"] and summary["counts"]["libero_10/1"]
