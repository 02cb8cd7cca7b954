"""The evaluation harness: results store, method configs, runs end to end, resume, Ray."""

from __future__ import annotations

import hashlib
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

from seal.errors import InvalidInput
from seal.eval.backends import LocalBackend
from seal.eval.execute import RunOptions
from seal.eval.runner import run_eval
from seal.eval.store import ResultStore, TrialRow
from seal.eval.trials import MethodSpec, TrialSpec, expand, parse_methods

SHORT = 25  # control steps per trial: the harness is under test here, not the policy


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ---- store --------------------------------------------------------------------------------
def test_store_round_trip_and_no_duplicates(tmp_path):
    db = tmp_path / "r.db"
    row = TrialRow(method="seal", config_hash="abc", suite="libero_10", task=3, trial=7, init_index=7, seed=1,
                   success=True, steps=120, subplans=["pick up the bowl"], goal_status={"In(a,b)": True})
    with ResultStore(db) as store:
        assert store.add(row) is True
        assert store.add(row) is False  # the same trial twice is refused, not duplicated
    with ResultStore(db, create=False) as store:
        (back,) = store.rows()
    assert back.success is True and back.subplans == ["pick up the bowl"] and back.goal_status == {"In(a,b)": True}
    assert back.key == row.key


def test_store_refuses_foreign_and_corrupted_files(tmp_path):
    text = tmp_path / "notes.db"
    text.write_text("my thesis results, do not delete\n")
    foreign = tmp_path / "foreign.db"
    con = sqlite3.connect(foreign)
    con.execute("CREATE TABLE experiments (x INTEGER)")
    con.commit()
    con.close()
    for path, words in ((text, "not a SQLite file"), (foreign, "not a SEAL results database")):
        before = _digest(path)
        with pytest.raises(InvalidInput, match=words):
            ResultStore(path)
        assert _digest(path) == before  # never overwritten
    with pytest.raises(InvalidInput, match="no results database"):
        ResultStore(tmp_path / "missing.db", create=False)


def test_store_refuses_newer_schema(tmp_path):
    db = tmp_path / "r.db"
    ResultStore(db).close()
    con = sqlite3.connect(db)
    con.execute("UPDATE seal_meta SET value = '99' WHERE key = 'schema_version'")
    con.commit()
    con.close()
    with pytest.raises(InvalidInput, match="schema v99"):
        ResultStore(db)


# ---- methods and trials -------------------------------------------------------------------
def test_parse_methods_and_config_hashes():
    base, seal, seal5 = parse_methods("base,seal,seal:k=5:rounds=1", knobs="misaligned")
    assert (base.label, seal.label, seal5.label) == ("base", "seal", "seal[k=5,rounds=1]")
    assert seal5.k == 5 and seal5.rounds == 1
    # K does not change what `base` does, so it does not change its hash either
    assert MethodSpec(method="base", k=3).config_hash == MethodSpec(method="base", k=10).config_hash
    assert MethodSpec(k=3).config_hash != MethodSpec(k=10).config_hash
    with pytest.raises(InvalidInput, match="valid: base, random, value, seal"):
        parse_methods("sael")
    with pytest.raises(InvalidInput, match="no V-GPS checkpoint at no_such_run"):
        parse_methods("value:value_ckpt=no_such_run")
    with pytest.raises(InvalidInput, match="name=value"):
        parse_methods("seal:kk=3")
    with pytest.raises(InvalidInput, match="must be an integer"):
        parse_methods("seal:k=many")
    with pytest.raises(InvalidInput, match="valid: oracle, openai, gemini"):
        parse_methods("seal", verifier="gpt")
    with pytest.raises(InvalidInput, match="listed twice"):
        parse_methods("seal,seal:k=10")


def test_trials_share_starts_across_methods():
    methods = parse_methods("base,seal")
    trials = expand(methods, ["libero_10"], [0, 2], trials=3)
    assert len(trials) == 2 * 3 * 2
    by_key = {}
    for t in trials:
        by_key.setdefault((t.task, t.trial), set()).add((t.init_index, t.seed))
    assert all(len(v) == 1 for v in by_key.values())  # same init state and seed for every method
    assert [t.task for t in trials[:6]] == [0] * 6  # one task's trials run together
    with pytest.raises(InvalidInput, match="valid ids"):
        expand(methods, ["libero_10"], [10], trials=1)
    with pytest.raises(InvalidInput, match="valid suites"):
        expand(methods, ["libero_11"], None, trials=1)


# ---- running ------------------------------------------------------------------------------
def test_tiny_run_end_to_end_and_resume(tmp_path):
    """2 tasks x 2 trials x 2 methods into the store; the same command again runs nothing."""
    db = tmp_path / "results.db"
    methods = parse_methods("base,seal:k=2")
    options = RunOptions(out_dir=str(tmp_path / "runs"), video="none", max_steps=SHORT)
    seen = []
    summary = run_eval(str(db), methods, ["libero_10"], [0, 1], 2, options=options,
                       on_row=lambda row, ran, total: seen.append((ran, total)))
    assert (summary.planned, summary.ran, summary.errors) == (8, 8, 0)
    assert seen[-1] == (8, 8)
    with ResultStore(db) as store:
        rows = store.rows()
        assert {r.method for r in rows} == {"base", "seal[k=2]"}
        assert all(r.status == "ok" and r.steps <= SHORT + 5 and Path(r.trace_path).exists() for r in rows)
        assert all(r.verifier_calls > 0 for r in rows if r.method.startswith("seal"))
        assert all(r.ended_by == _events(r)[-1]["ended_by"] and r.ended_by for r in rows)
        assert set(store.methods()) == {m.config_hash for m in methods}
        # The alignment audit: every commit is audited against simulator truth, for base as for seal, and
        # an oracle-verified commit must be audited as achieved (same grounding, same committed state).
        assert sum(r.subplans_audited for r in rows) > 0
        for r in rows:
            commits = [e for e in _events(r) if e["event"] == "commit"]
            audited = [e["aligned"] for e in commits if e["aligned"] is not None]
            assert (r.subplans_audited, r.subplans_aligned) == (len(audited), sum(audited))
            # the oracle checks a pick with Held: its passes hold under the audit's Held answer, same check
            assert all(e["aligned_held"] for e in commits if (e["verdict"] or {}).get("success"))
            assert all((e["aligned"] is None) == (e["aligned_held"] is None) for e in commits)
    assert set(summary.alignment) == {"base", "seal[k=2]"}
    assert all(v is None or 0 <= v <= 1 for v in summary.alignment.values())
    again = run_eval(str(db), methods, ["libero_10"], [0, 1], 2, options=options)
    assert (again.already_done, again.ran) == (8, 0)
    # the capped trials are not the full-length ones: a run at the suite's limit must not count them as done
    for cap, said in ((None, "the suite's step limit"), (SHORT + 1, f"--max-steps {SHORT + 1}")):
        with pytest.raises(InvalidInput, match=f"run with --max-steps {SHORT}; this run asks for {said}"):
            run_eval(str(db), methods, ["libero_10"], [0, 1], 2, options=replace(options, max_steps=cap))


def _events(row):
    from seal.steer.trace import read_trace

    return read_trace(row.trace_path)


def test_value_method_runs_with_a_trained_checkpoint(tmp_path):
    """V-GPS in the harness: the checkpoint's bytes name the method; the trial runs for real."""
    from test_train_value import _bandit

    from seal.train.vgps import IQLConfig, train_value

    run = tmp_path / "vgps"
    train_value(_bandit(64, 0), run, IQLConfig(steps=2, batch_size=16, hidden=16))
    (spec,) = parse_methods(f"value:k=3:value_ckpt={run}")
    assert spec.label.startswith("value[ckpt=vgps")
    before = spec.config_hash
    summary = run_eval(str(tmp_path / "r.db"), [spec], ["libero_10"], [0], 1,
                       options=RunOptions(out_dir=str(tmp_path / "runs"), video="none", max_steps=SHORT))
    assert (summary.ran, summary.errors) == (1, 0)
    with ResultStore(tmp_path / "r.db") as store:
        (row,) = store.rows()
    assert row.status == "ok" and 0 < row.steps <= SHORT + 5
    train_value(_bandit(64, 0), run, IQLConfig(steps=4, batch_size=16, hidden=16))  # retrained in place
    assert MethodSpec(method="value", k=3, value_ckpt=str(run)).config_hash != before
    with pytest.raises(InvalidInput, match="no V-GPS checkpoint"):
        MethodSpec(method="value", value_ckpt=str(tmp_path / "missing")).config_hash


def test_crashing_trial_is_recorded_and_run_goes_on(tmp_path):
    base = MethodSpec(method="base")
    bad = TrialSpec(base, "libero_10", 0, trial=0, init_index=10_000, seed=0)  # no such init state
    good = TrialSpec(base, "libero_10", 0, trial=1, init_index=1, seed=1)
    backend = LocalBackend(RunOptions(out_dir=str(tmp_path), video="none", max_steps=10), workers=1)
    rows = {r.trial: r for r in backend.run([bad, good])}
    assert rows[0].status == "error" and "init" in rows[0].error and "Traceback" in rows[0].error
    assert rows[1].status == "ok" and rows[1].steps > 0


def test_retry_errors_runs_error_rows_again_and_replaces_them(tmp_path):
    db = tmp_path / "r.db"
    options = RunOptions(out_dir=str(tmp_path / "runs"), video="none", max_steps=10)
    run_eval(str(db), [MethodSpec(method="base")], ["libero_10"], [0], 2, options=options)
    with sqlite3.connect(db) as con:  # trial 1 crashed (say, a worker timed out)
        con.execute("UPDATE trials SET status = 'error', error = 'worker gave no answer' WHERE trial = 1")
    again = run_eval(str(db), [MethodSpec(method="base")], ["libero_10"], [0], 2, options=options)
    assert again.ran == 0 and again.already_done == 2  # without the flag an error is a result
    retried = run_eval(str(db), [MethodSpec(method="base")], ["libero_10"], [0], 2, options=options,
                       retry_errors=True)
    assert retried.ran == 1 and retried.errors == 0
    with sqlite3.connect(db) as con:
        rows = con.execute("SELECT trial, status, error FROM trials ORDER BY trial").fetchall()
    assert [(t, s) for t, s, _ in rows] == [(0, "ok"), (1, "ok")] and rows[1][2] == ""


def test_resume_after_killing_the_run(tmp_path):
    db = tmp_path / "results.db"
    cmd = [sys.executable, "-m", "seal.cli", "eval", "--suite", "libero_10", "--tasks", "0", "--trials", "4",
           "--methods", "base", "--db", str(db), "--max-steps", str(SHORT), "--video", "none"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.time() + 240
    n = 0
    while time.time() < deadline and proc.poll() is None:
        time.sleep(0.5)
        if db.exists():
            try:
                with ResultStore(db, create=False) as store:
                    n = store.count()
            except (InvalidInput, sqlite3.OperationalError):
                continue
            if n >= 1:
                break
    assert n >= 1, "the run never stored a trial"
    os.killpg(proc.pid, signal.SIGKILL)  # as hard as a crash or a lost machine
    proc.wait(30)
    with ResultStore(db) as store:
        before = {r.key: r.finished_at for r in store.rows()}
    assert 1 <= len(before) < 4
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    # The progress tally names methods as the report does, not by their stored keys.
    assert re.search(r"libero_10/0  scripted expert \d+/\d+", out.stderr), out.stderr
    with ResultStore(db) as store:
        rows = store.rows()
    assert sorted(r.trial for r in rows) == [0, 1, 2, 3]  # none lost, none duplicated
    assert all(before[r.key] == r.finished_at for r in rows if r.key in before)  # not run again


def test_ray_backend_on_a_local_cluster(tmp_path):
    methods = [MethodSpec(method="base")]
    # Separate run directories: with one, the Ray run would overwrite the local traces compared below.
    local = run_eval(str(tmp_path / "local.db"), methods, ["libero_10"], [0], 2,
                     options=RunOptions(out_dir=str(tmp_path / "local_runs"), video="none", max_steps=SHORT))
    ray_run = run_eval(str(tmp_path / "ray.db"), methods, ["libero_10"], [0], 2, backend="ray", workers=2,
                       options=RunOptions(out_dir=str(tmp_path / "ray_runs"), video="none", max_steps=SHORT))
    assert ray_run.ran == local.ran == 2
    with ResultStore(tmp_path / "local.db") as a, ResultStore(tmp_path / "ray.db") as b:
        ra, rb = a.rows(), b.rows()
    assert all(r.worker.startswith("ray-") for r in rb)
    # Seeded policy, exact simulator: the same trials give the same episodes on either backend. What
    # is compared is what was executed - the content hash of every committed state - not outcomes
    # (at this step cap every trial fails at the same step count, whatever ran).
    assert all("local_runs" in r.trace_path for r in ra) and all("ray_runs" in r.trace_path for r in rb)
    local_runs, ray_runs = {r.trial: _commits(r) for r in ra}, {r.trial: _commits(r) for r in rb}
    assert local_runs == ray_runs and set(local_runs) == {0, 1}
    assert all(local_runs.values()) and local_runs[0] != local_runs[1]  # two different episodes, each matched


def _commits(row: TrialRow) -> list[str]:
    """The snapshot ids (content hashes of the whole simulator state) committed in a trial, in order."""
    from seal.steer.trace import read_trace

    return [e["snapshot"] for e in read_trace(row.trace_path) if e["event"] == "commit"]


def test_store_migrates_an_older_schema(tmp_path):
    db = tmp_path / "r.db"
    with ResultStore(db) as store:
        store.add(TrialRow(method="base", config_hash="h", suite="libero_10", task=0, trial=0, init_index=0, seed=0))
    con = sqlite3.connect(db)  # make it look like a v1 file (before policy_s and the verifier-error columns)
    for column in ("policy_s", "verifier_errors", "verifier_unavailable", "subplans_audited", "subplans_aligned",
                   "ended_by", "done_refusals"):
        con.execute(f"ALTER TABLE trials DROP COLUMN {column}")
    con.execute("UPDATE seal_meta SET value = '1' WHERE key = 'schema_version'")
    con.commit()
    con.close()
    with ResultStore(db) as store:
        (row,) = store.rows()
    assert row.policy_s == 0.0 and row.verifier_errors == 0 and row.verifier_unavailable is False
    assert (row.subplans_audited, row.subplans_aligned, row.ended_by, row.done_refusals) == (0, 0, "", 0)
    con = sqlite3.connect(db)
    assert con.execute("SELECT value FROM seal_meta WHERE key = 'schema_version'").fetchone()[0] == "6"
    con.close()


def test_workers_die_with_a_killed_coordinator(tmp_path):
    """An orphaned worker would finish its trial and write into files a resumed run rewrites."""
    db = tmp_path / "results.db"
    cmd = [sys.executable, "-m", "seal.cli", "eval", "--suite", "libero_10", "--tasks", "0", "--trials", "6",
           "--methods", "base", "--db", str(db), "--max-steps", str(SHORT), "--video", "none"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline, rows = time.time() + 240, []
    while time.time() < deadline and proc.poll() is None and not rows:
        time.sleep(0.5)
        try:
            with ResultStore(db, create=False) as store:
                rows = store.rows()
        except (InvalidInput, sqlite3.OperationalError):
            continue
    assert rows, "the run never stored a trial"
    worker_pid = int(rows[0].worker.rsplit(":", 1)[1])
    os.kill(proc.pid, signal.SIGKILL)  # the coordinator only: no cleanup code runs
    proc.wait(30)
    for _ in range(40):
        if not Path(f"/proc/{worker_pid}").exists():
            break
        time.sleep(0.25)
    assert not Path(f"/proc/{worker_pid}").exists(), "the worker outlived its coordinator"
