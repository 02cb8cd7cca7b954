"""`seal report`'s "Why episodes failed": one cause per failed trial, from the stored row and its trace."""

from __future__ import annotations

import csv
import json

from seal.eval.store import ResultStore, TrialRow
from seal.eval.trials import MethodSpec
from seal.report import write_report
from seal.report.causes import plan_reads_goal
from seal.sim.suites import get_task

BASE, SEAL = MethodSpec(method="base"), MethodSpec(k=10)
# LIBERO-10 task 0: put both the alphabet soup and the tomato sauce in the basket
RIGHT = ["pick up the alphabet soup", "place it in the basket", "pick up the tomato sauce", "place it in the basket"]
WRONG = ["pick up the butter", "place it in the basket", "pick up the tomato sauce", "place it in the basket"]


def test_a_plan_is_read_against_the_goal():
    assert plan_reads_goal("libero_10", 0, RIGHT) is True
    assert plan_reads_goal("libero_10", 0, WRONG) is False
    assert plan_reads_goal("libero_10", 0, RIGHT[:2]) is False  # half the task
    # the rephrased suite's goal is the same; the plan is read against objects, not wording
    assert plan_reads_goal("lang_rephrase", 0, RIGHT) is True
    assert plan_reads_goal("libero_10", 0, []) is None  # no plan stored
    # a policy that does not reason (the twin) stores the instruction as its one sub-plan: not a misread
    assert plan_reads_goal("libero_10", 0, ["put both the alphabet soup and the tomato sauce in the basket"]) is None
    assert plan_reads_goal("lang_rephrase", 0, [get_task("lang_rephrase", 0).instruction]) is None
    # two alike butters: the parser cannot tell which one its own scripted plan means, so it judges none
    assert plan_reads_goal("libero_90", 3, ["pick up the butter", "place it in the top drawer"]) is None


def _trace(path, commits):
    """Commits in plan order: the first for the plan's first sub-plan (a pick), the second for its second (a place).
    A commit is (passed, aligned) as older traces hold it, or (passed, aligned, aligned_held)."""
    path.parent.mkdir(parents=True)
    events = [e for i, (ok, aligned, *held) in enumerate(commits)
              for e in ({"event": "subplan", "step": 0, "text": RIGHT[i]},
                        {"event": "commit", "slot": 0, "verdict": {"success": ok}, "aligned": aligned,
                         **({"aligned_held": held[0]} if held else {})})]
    path.write_text("".join(json.dumps(e) + "\n" for e in events) + '{"event": "commit", "verdict"')  # a cut-off line


def test_each_failure_gets_its_first_cause(tmp_path):
    db = tmp_path / "r.db"
    trials = [  # (method, success, plans, ended_by, fallbacks, commits in the trace or None, status)
        (BASE, True, RIGHT, "goal_holds", 0, None, "ok"),
        (BASE, False, RIGHT, "step_limit", 0, None, "ok"),  # out of steps (no trace needed: no verifier)
        (BASE, False, WRONG, "step_limit", 0, None, "ok"),  # misread
        (BASE, False, RIGHT, "policy_finished", 0, None, "ok"),  # false claim
        (SEAL, False, RIGHT, "step_limit", 1, [(True, True), (True, False)], "ok"),  # verifier passed a miss
        (SEAL, False, WRONG, "step_limit", 0, [(True, False)], "ok"),  # misread comes first
        (SEAL, False, RIGHT, "step_limit", 2, [(True, True), (False, False)], "ok"),  # no candidate passed
        (SEAL, False, RIGHT, "step_limit", 0, None, "error"),  # crashed
        (SEAL, False, RIGHT, "step_limit", 0, None, "ok"),  # out of steps, its trace not on disk
        (SEAL, True, RIGHT, "goal_holds", 0, [(True, False)], "ok"),  # a success is no failure
    ]
    with ResultStore(db) as store:
        for spec in (BASE, SEAL):
            store.register_method(spec.config_hash, spec.label, spec.canonical())
        for t, (spec, ok, plans, ended, fallbacks, commits, status) in enumerate(trials):
            trace = ""
            if commits is not None:
                path = tmp_path / "runs" / f"t{t}" / "trace.jsonl"
                _trace(path, commits)
                trace = str(path)
            store.add(TrialRow(method=spec.label, config_hash=spec.config_hash, suite="libero_10", task=0, trial=t,
                               init_index=t, seed=t, success=ok, steps=100, wall_s=1.0, subplans=plans,
                               ended_by=ended, fallbacks=fallbacks, trace_path=trace, status=status,
                               error="boom" if status == "error" else ""))
    report = write_report(db, tmp_path / "out", episodes=False)
    path = next(p for p in report.csv if p.name == "failure_causes.csv")
    rows = {r["config_hash"]: r for r in csv.DictReader(path.read_text().splitlines())}
    base, seal = rows[BASE.config_hash], rows[SEAL.config_hash]
    counts = lambda r: {k: int(v) for k, v in r.items()  # noqa: E731
                        if k not in ("suite", "method", "config_hash", "misread_tasks")}
    assert (base["misread_tasks"], seal["misread_tasks"]) == ("0", "0")  # which task's instruction was misread
    assert counts(base) == {"trials": 4, "failures": 3, "misread": 1, "verifier_passed_a_miss": 0,
                            "false_claim_of_completion": 1, "no_candidate_passed": 0, "out_of_steps": 1,
                            "crashed": 0, "failures_without_trace": 0}
    assert counts(seal) == {"trials": 6, "failures": 5, "misread": 1, "verifier_passed_a_miss": 1,
                            "false_claim_of_completion": 0, "no_candidate_passed": 1, "out_of_steps": 1,
                            "crashed": 1, "failures_without_trace": 1}
    md = report.markdown.read_text()
    assert "### Why episodes failed" in md and "had no trace on disk" in md
    assert "| 4 | 3 | 1 (33%), task 0 |" in md  # base: the misread cell names the task
    # the passes SEAL committed, solved trials too: (T,T)+(T,F), (T,F), (T,T)+(F,F), and the success's (T,F):
    # 5 passes, 2 held; the crashed and the trace-less trial are left out, and a base has no such row
    path = next(p for p in report.csv if p.name == "committed_passes.csv")
    (row,) = list(csv.DictReader(path.read_text().splitlines()))
    assert row["config_hash"] == SEAL.config_hash
    assert (row["trials"], row["committed_passes"], row["held"], row["trials_without_trace"]) == ("6", "5", "2", "2")
    assert "| libero_10 | scripted expert + SEAL (oracle) | 4 of 6 | 5 | 2 | 0.400 [0.118, 0.769] |" in md
    assert "2 trial(s) had no trace on disk" in md
    # by kind: the picks (T,T), (T,F), (T,T), (T,F) -> 2 of 4 held; the one place passed, (T,F), did not hold
    path = next(p for p in report.csv if p.name == "committed_passes_by_kind.csv")
    kinds = {r["kind"]: (r["committed_passes"], r["held"]) for r in csv.DictReader(path.read_text().splitlines())}
    assert kinds == {"pick": ("4", "2"), "place": ("1", "0")}
    assert "| libero_10 | scripted expert + SEAL (oracle) | 2/4 = 0.500 [0.150, 0.850] | 0/1 = 0.000 [0.000, 0.793] |" in md


def test_a_carried_pick_is_no_miss_where_the_trace_has_the_held_audit(tmp_path):
    """A pick the pad check calls missed but ``Held`` calls picked (an object on a finger's body): the failure is
    not the verifier's, and the pass counts as held; a trace without the Held answer falls back to the pad check."""
    db = tmp_path / "r.db"
    trials = [[(True, False, True), (False, False, False)],  # pads says missed, Held says picked: no candidate passed
              [(True, False)]]  # an older trace: the pad check decides, the verifier passed a miss
    with ResultStore(db) as store:
        store.register_method(SEAL.config_hash, SEAL.label, SEAL.canonical())
        for t, commits in enumerate(trials):
            path = tmp_path / "runs" / f"t{t}" / "trace.jsonl"
            _trace(path, commits)
            store.add(TrialRow(method=SEAL.label, config_hash=SEAL.config_hash, suite="libero_10", task=0, trial=t,
                               init_index=t, seed=t, success=False, steps=100, wall_s=1.0, subplans=RIGHT,
                               ended_by="step_limit", fallbacks=1, trace_path=str(path)))
    report = write_report(db, tmp_path / "out", episodes=False)
    path = next(p for p in report.csv if p.name == "failure_causes.csv")
    (row,) = list(csv.DictReader(path.read_text().splitlines()))
    assert (row["verifier_passed_a_miss"], row["no_candidate_passed"]) == ("1", "1")
    path = next(p for p in report.csv if p.name == "committed_passes.csv")
    (row,) = list(csv.DictReader(path.read_text().splitlines()))
    assert (row["committed_passes"], row["held"]) == ("2", "1")


def test_a_configuration_without_traces_shows_no_count_of_passes(tmp_path):
    """Traces lost (or never written): the committed-pass row says so instead of reading as a verifier that
    never passed."""
    db = tmp_path / "r.db"
    with ResultStore(db) as store:
        store.register_method(SEAL.config_hash, SEAL.label, SEAL.canonical())
        for t in range(3):
            store.add(TrialRow(method=SEAL.label, config_hash=SEAL.config_hash, suite="libero_10", task=0, trial=t,
                               init_index=t, seed=t, success=False, steps=100, wall_s=1.0, subplans=RIGHT,
                               ended_by="step_limit", fallbacks=1, trace_path=str(tmp_path / "gone" / "trace.jsonl")))
    md = write_report(db, tmp_path / "out", episodes=False).markdown.read_text()
    assert "| libero_10 | scripted expert + SEAL (oracle) | 0 of 3 | no trace | no trace | - |" in md


def test_candidates_are_counted_per_kind_of_the_subplan_they_were_sampled_for(tmp_path):
    """Every judged candidate counts under the last sub-plan before it; a candidate that crashed before a
    verdict, and a cut-off last line, count nowhere."""
    db = tmp_path / "r.db"
    path = tmp_path / "runs" / "t0" / "trace.jsonl"
    path.parent.mkdir(parents=True)
    verdicts = {"pick up the alphabet soup": [False] * 9 + [True], "place it in the basket": [True, False]}
    events = []
    for text, passed in verdicts.items():
        events.append({"event": "subplan", "text": text})
        events += [{"event": "candidate", "slot": i, "verdict": {"success": ok}} for i, ok in enumerate(passed)]
    events.append({"event": "candidate", "slot": 2, "verdict": None, "error": "simulator crashed"})
    path.write_text("".join(json.dumps(e) + "\n" for e in events) + '{"event": "candidate", "verd')
    with ResultStore(db) as store:
        store.register_method(SEAL.config_hash, SEAL.label, SEAL.canonical())
        store.add(TrialRow(method=SEAL.label, config_hash=SEAL.config_hash, suite="libero_10", task=0, trial=0,
                           init_index=0, seed=0, success=False, steps=100, wall_s=1.0, subplans=RIGHT,
                           ended_by="step_limit", trace_path=str(path)))
        store.add(TrialRow(method=SEAL.label, config_hash=SEAL.config_hash, suite="libero_10", task=0, trial=1,
                           init_index=1, seed=1, success=False, steps=100, wall_s=1.0, subplans=RIGHT,
                           ended_by="step_limit", trace_path=str(tmp_path / "gone" / "trace.jsonl")))
    report = write_report(db, tmp_path / "out", episodes=False)
    path = next(p for p in report.csv if p.name == "candidates_by_kind.csv")
    rows = {r["kind"]: r for r in csv.DictReader(path.read_text().splitlines())}
    assert {k: (r["candidates"], r["passed"]) for k, r in rows.items()} == {"pick": ("10", "1"), "place": ("2", "1")}
    assert rows["pick"]["traced_trials"] == "1"  # the trial without a trace is left out
    assert "| 1 | 2/12 = 0.17 | 1/10 = 0.10 | 1/2 = 0.50 |" in report.markdown.read_text()
