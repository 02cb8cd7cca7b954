"""scripts/generalization.sh and its plan helper: the plan's JSON, the commands the script would run,
and one real 10-step trial of the reasoning VLA into a scratch database, run twice (the second run
must find it stored and run nothing)."""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "generalization.sh"
PLAN = ROOT / "scripts" / "generalization_plan.py"
SUITES = ["libero_10", "lang_rephrase", "lang_object_property", "visual_scene", "visual_viewpoint", "composition"]
SHORT = ["twin", "twin_vgps", "vla", "vla_seal", "vla_seal_learned"]
TASKS = {"composition": 13}  # every other suite has LIBERO-10's ten tasks


def _env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in (
        "DB", "TRIALS", "COMP_TRIALS", "SUITES", "TASKS", "METHODS", "MAX_STEPS", "VALUE_CKPT", "SEAL", "REPORT_ARGS",
        "RETRY_ERRORS")}
    return env | extra


def _run(cmd, env, cwd, timeout=300) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True, timeout=timeout)


def test_plan_counts_trials_and_hours(tmp_path):
    out = _run([sys.executable, str(PLAN)], _env(TRIALS="2", COMP_TRIALS="4"), tmp_path)
    assert out.returncode == 0, out.stderr
    plan = json.loads(out.stdout)
    assert list(plan["suites"]) == SUITES
    for suite, entry in plan["suites"].items():
        n = 4 if suite == "composition" else 2
        tasks = TASKS.get(suite, 10)
        assert entry["tasks"] == tasks and entry["trials_per_task"] == n
        assert list(entry["methods"]) == SHORT
        for m in entry["methods"].values():
            assert m["trials"] == tasks * n and m["to_run"] == tasks * n and m["done"] == 0
            assert m["cpu_hours"] > 0 and m["s_per_trial"] > 0 and m["cost_source"] == "default"
        assert entry["cpu_hours"] > 0
    # without VALUE_CKPT, twin + V-GPS runs the package's shipped Q-function: nothing is skipped
    assert plan["skipped"] == {}
    assert plan["suites"]["libero_10"]["methods"]["twin_vgps"]["method"] == "value:policy=vla:policy_ckpt=twin:k=10"
    runs = sum(m["trials"] for e in plan["suites"].values() for m in e["methods"].values() if m["runs"])
    assert plan["total_trials"] == runs == 5 * (5 * 10 * 2 + 13 * 4)
    assert plan["total_cpu_hours"] > 0
    # SEAL costs more per trial than the policy alone
    l10 = plan["suites"]["libero_10"]["methods"]
    assert l10["vla_seal"]["s_per_trial"] > l10["vla"]["s_per_trial"]
    # the LIBERO-100 training column: its evaluation is the three VLA methods' share of this plan
    column = plan["libero_100_column"]
    vla_hours = sum(e["methods"][m]["cpu_hours"] for e in plan["suites"].values()
                    for m in ("vla", "vla_seal", "vla_seal_learned"))
    assert abs(column["eval_cpu_hours"] - vla_hours) < 0.1
    assert column["demos_to_record"] > 4000 and column["train_steps"] > 6000
    assert abs(column["total_cpu_hours"] - column["record_cpu_hours"] - column["train_cpu_hours"]
               - column["eval_cpu_hours"]) < 0.2


def test_dry_run_matches_plan(tmp_path):
    """The script and the plan helper name the same method strings in the same order."""
    env = _env(DB=str(tmp_path / "g.db"), TRIALS="2", COMP_TRIALS="4")
    dry = _run(["bash", str(SCRIPT), "--dry-run"], env, tmp_path)
    assert dry.returncode == 0, dry.stderr
    plan = json.loads(_run(["bash", str(SCRIPT), "--plan"], env, tmp_path).stdout)
    want = [(s, m["method"], e["trials_per_task"]) for s, e in plan["suites"].items()
            for m in e["methods"].values() if m["runs"]]
    got = []
    lines = dry.stdout.splitlines()
    for line in lines:  # one command per suite, every method in it: trials are paired start by start
        words = line.split()
        got += [(words[words.index("--suite") + 1], method, int(words[words.index("--trials") + 1]))
                for method in words[words.index("--methods") + 1].split(",")]
        assert "--render fast --workers 1 --video none" in line and str(tmp_path / "g.db") in line
    assert got == want and len(got) == 6 * 5 and len(lines) == 6
    # WORKERS runs trials in parallel; a bad value is refused with the names of the knobs
    two = _run(["bash", str(SCRIPT), "--dry-run"], env | {"WORKERS": "2"}, tmp_path)
    assert all("--workers 2 " in line for line in two.stdout.splitlines()), two.stdout
    strict = _run(["bash", str(SCRIPT), "--dry-run"], env | {"LEARNED_THRESHOLD": "0.8"}, tmp_path)
    assert "seal:policy=vla:k=10:verifier=learned:threshold=0.8" in strict.stdout
    plan = json.loads(_run(["bash", str(SCRIPT), "--plan"], env | {"LEARNED_THRESHOLD": "0.8"}, tmp_path).stdout)
    assert plan["suites"]["libero_10"]["methods"]["vla_seal_learned"]["method"].endswith(":threshold=0.8")
    zero = _run(["bash", str(SCRIPT), "--dry-run"], env | {"WORKERS": "0"}, tmp_path)
    assert zero.returncode == 2 and "WORKERS" in zero.stderr and "got '0'" in zero.stderr

    # a VALUE_CKPT directory without weights: refused before anything runs or any database is made
    bad = tmp_path / "not_a_value_run"
    bad.mkdir()
    out = _run(["bash", str(SCRIPT)], env | {"VALUE_CKPT": str(bad), "METHODS": "twin_vgps,vla"}, tmp_path)
    assert out.returncode == 2 and "no V-GPS checkpoint" in out.stderr, out.stderr
    assert not (tmp_path / "g.db").exists()
    plan = json.loads(_run(["bash", str(SCRIPT), "--plan"], env | {"VALUE_CKPT": str(bad)}, tmp_path).stdout)
    assert "no V-GPS checkpoint" in plan["skipped"]["twin_vgps"]


def _rows(db: Path) -> list[tuple]:
    with sqlite3.connect(db) as c:
        return c.execute("SELECT method, suite, task, trial, steps, finished_at FROM trials").fetchall()


def test_script_runs_one_trial_and_resumes(tmp_path):
    db = tmp_path / "eval" / "g.db"
    env = _env(DB=str(db), SUITES="libero_10", TASKS="5", TRIALS="1", MAX_STEPS="10", METHODS="vla",
               MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    cwd = tmp_path / "elsewhere"  # the script must not depend on the current directory
    cwd.mkdir()
    start = time.perf_counter()
    first = _run(["bash", str(SCRIPT)], env, cwd)
    took = time.perf_counter() - start
    assert first.returncode == 0, first.stdout[-2000:] + first.stderr[-2000:]
    rows = _rows(db)
    assert len(rows) == 1
    method, suite, task, trial, steps, finished = rows[0]
    assert method.startswith("base[policy=vla") and (suite, task, trial) == ("libero_10", 5, 0) and steps == 10
    assert (db.parent / "g_logs" / "libero_10.log").is_file()
    assert (db.parent / "g_report" / "report.md").is_file()
    assert '"ran": 1' in first.stdout

    second = _run(["bash", str(SCRIPT)], env, cwd)
    assert second.returncode == 0, second.stderr[-2000:]
    assert '"ran": 0' in second.stdout and '"already_done": 1' in second.stdout
    assert _rows(db) == rows  # the same row, untouched: the trial did not run again

    # the plan now counts the stored trial as done and takes its cost from it
    plan = json.loads(_run(["bash", str(SCRIPT), "--plan"], env, cwd).stdout)
    vla = plan["suites"]["libero_10"]["methods"]["vla"]
    assert (vla["trials"], vla["done"], vla["to_run"]) == (1, 1, 0)
    assert vla["cost_source"].startswith("db:")
    print(f"first run {took:.1f} s")


def test_a_cost_carried_to_another_suite_is_scaled_by_what_other_configurations_measured_there():
    import importlib.util

    spec = importlib.util.spec_from_file_location("generalization_plan", PLAN)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    seal = {"method": "seal", "verifier": "oracle"}
    kinds = {"new": seal | {"policy_ckpt": "b"}, "old": seal | {"policy_ckpt": "a"},
             "base": {"method": "base", "policy_ckpt": "a"}}
    rows = {("new", "libero_10"): [(100.0, 300)],
            ("old", "libero_10"): [(50.0, 300), (70.0, 300)], ("old", "visual_scene"): [(180.0, 500)],
            ("base", "libero_10"): [(10.0, 520)], ("base", "visual_scene"): [(100.0, 520)]}  # another method: ignored
    got, source = mod._pick(rows, kinds, "new", kinds["new"], "visual_scene")
    assert got == [(300.0, 300)] and "x3.00 for visual_scene" in source and "1 other" in source
    # measured in the suite itself: taken as it is
    assert mod._pick(rows, kinds, "old", kinds["old"], "visual_scene") == ([(180.0, 500)],
                                                                          "db: this configuration, visual_scene")
    # no other configuration of the method ran the suite: the other suites' cost, unscaled
    assert mod._pick(rows, kinds, "new", kinds["new"], "composition") == ([(100.0, 300)],
                                                                         "db: this configuration, other suites")
