"""Why episodes failed: one cause per failed trial, from what the trial stored and its trace.

The generalization tables must say *why* SEAL's lift is larger or smaller out of distribution: did
the policy misread the instruction, did its actions miss plans it read right (an unseen view), or
did the verifier let a miss through? Each failure gets the first cause that applies, in the order a
failure propagates through the Hypothesize-Predict-Verify loop:

1. ``misread``: the plan the policy wrote does not lead to the task's goal. The plan is grounded
   with the oracle's own parser against the task's objects and goal regions (no simulator needed),
   and every goal atom must be among what its sub-plans achieve. Tasks whose own scripted plan the
   parser cannot ground to the goal are not judged (some LIBERO-90 scenes with two alike objects).
2. ``verifier passed a miss``: a commit the verifier accepted whose sub-plan did not hold by
   simulator truth (the commit's alignment audit, in the trace: a pick checked with ``Held`` where the
   trace records it, with robosuite's pad check in traces written before that).
3. ``false claim of completion``: the episode ended on the policy's word that the task was done.
4. ``no candidate passed``: some round had no candidate the verifier accepted (a fallback).
5. ``out of steps``: the plan was right and nothing above happened; the actions were too slow or
   too far off to finish in the step budget.
6. ``crashed``: an error trial.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache

from seal.errors import InvalidInput
from seal.eval.store import TrialRow
from seal.report.data import MethodInfo, ReportData, succeeded
from seal.report.stats import wilson
from seal.report.tables import Table, to_csv
from seal.verify.dataset import KINDS, subplan_kind

CAUSES = ("misread", "verifier passed a miss", "false claim of completion", "no candidate passed", "out of steps",
          "crashed")


@cache
def _goal_check(suite: str, task: int):
    """(goal atoms, names to ground against, the instruction) of a task, or None if the parser cannot
    judge its plans."""
    from seal.policies.expert.plan import bddl_names, plan_task
    from seal.sim.suites import get_task

    try:
        spec = get_task(suite, task)
    except InvalidInput:
        return None
    goal = frozenset(str(a) for a in spec.goal_atoms())
    # the goal's regions (basket_1_contain_region, ...) are sites of the objects' models, not BDDL names
    names = sorted(set(bddl_names(spec.bddl_path.read_text())) | {x for a in spec.goal_atoms() for x in a.args})
    if not goal <= _achieved([s.text for s in plan_task(spec)], names):
        return None
    return goal, names, spec.instruction


def _achieved(plans: list[str], names: list[str]) -> set[str]:
    from seal.verify.oracle import ground

    return {str(a) for i, p in enumerate(plans) for a in ground(p, tuple(plans), names, i).atoms}


def plan_reads_goal(suite: str, task: int, plans: list[str]) -> bool | None:
    """Does a written plan lead to the task's goal? None: no plan, or a task the parser cannot judge.
    A policy that does not reason (the twin) stores the instruction as its one sub-plan: that is no
    plan it wrote, so it is not judged either."""
    check = _goal_check(suite, task)
    if check is None or not plans:
        return None
    goal, names, instruction = check
    if list(plans) == [instruction]:
        return None
    return goal <= _achieved(list(plans), names)


@dataclass(frozen=True)
class Commit:
    passed: bool  # the verifier accepted the committed candidate
    held: bool | None  # its sub-plan held by simulator truth; None if the commit was not audited
    kind: str  # pick / place / open / close / turn / other, from the sub-plan's text


def _trace_events(trace, name: str):
    """(the sub-plan in force, event) for each ``name`` event of a trace, in order: the sub-plan is the text
    of the trace's last ``subplan`` event before it ("" before the first). A line cut off by a killed run is
    skipped."""
    subplan = ""
    with open(trace) as f:
        for line in f:
            if f'"{name}"' not in line and '"subplan"' not in line:
                continue
            try:
                event = json.loads(line)
            except ValueError:
                continue
            if event.get("event") == "subplan":
                subplan = event.get("text") or ""
            elif event.get("event") == name:
                yield subplan, event


def _commits(data: ReportData, row: TrialRow) -> list[Commit] | None:
    """Every commit in the trial's trace, with the kind of sub-plan it was made for. None: no trace on disk."""
    trace = data.resolve(row.trace_path)
    if trace is None:
        return None
    out = []
    for subplan, event in _trace_events(trace, "commit"):
        # the Held audit where the trace has it (a carried object is picked); older traces: the pad check
        held = event["aligned_held"] if "aligned_held" in event else event.get("aligned")
        out.append(Commit((event.get("verdict") or {}).get("success") is True, held, subplan_kind(subplan)))
    return out


def _verifier_passed_a_miss(data: ReportData, row: TrialRow) -> bool | None:
    """Did the verifier accept a commit whose sub-plan did not hold? None: no trace on disk."""
    commits = _commits(data, row)
    return None if commits is None else any(c.passed and c.held is False for c in commits)


def cause_of(data: ReportData, row: TrialRow, verifies: bool) -> tuple[str, bool]:
    """The cause of one failed trial, and whether its trace was missing (the verifier check skipped).
    ``verifies``: the trial's method asks a verifier (SEAL), so its commits are read for misses."""
    if row.status == "error":
        return "crashed", False
    if plan_reads_goal(row.suite, row.task, row.subplans) is False:
        return "misread", False
    missed = _verifier_passed_a_miss(data, row) if verifies else False
    if missed:
        return "verifier passed a miss", False
    if data.ended_by(row) == "policy_finished":
        return "false claim of completion", missed is None
    if row.fallbacks > 0:
        return "no candidate passed", missed is None
    return "out of steps", missed is None


@dataclass
class CauseRow:
    suite: str
    method: MethodInfo
    trials: int
    failures: int
    counts: dict  # cause -> failed trials
    no_trace: int  # failures whose trace was not on disk: a verifier's misses could not be counted
    misread_tasks: list  # tasks with a misread failure: which instructions the policy read wrong


def cause_rows(data: ReportData) -> list[CauseRow]:
    out = []
    for suite in data.suites:
        for m in data.methods_in(suite):
            rows = [r for r in data.rows if r.suite == suite and r.config_hash == m.config_hash]
            counts = dict.fromkeys(CAUSES, 0)
            no_trace, misread = 0, set()
            failed = [r for r in rows if not succeeded(r)]
            for r in failed:
                cause, missing = cause_of(data, r, verifies=m.method == "seal")
                counts[cause] += 1
                no_trace += missing
                if cause == "misread":
                    misread.add(r.task)
            out.append(CauseRow(suite, m, len(rows), len(failed), counts, no_trace, sorted(misread)))
    return out


def cause_display(rows: list[CauseRow]) -> Table:
    used = [c for c in CAUSES if any(r.counts[c] for r in rows)]
    headers = ["Suite", "Method", "trials", "failures"] + used

    def cell(n: int, of: int) -> str:
        return f"{n} ({100 * n / of:.0f}%)" if n else "0"

    def cells(r: CauseRow) -> list[str]:
        out = [cell(r.counts[c], r.failures) for c in used]
        if r.misread_tasks:  # which instructions were read wrong, not only how often
            i = used.index("misread")
            out[i] += f", task{'s' * (len(r.misread_tasks) > 1)} {', '.join(map(str, r.misread_tasks))}"
        return out

    body = [[r.suite, r.method.label, str(r.trials), str(r.failures)] + cells(r) for r in rows]
    notes = ["Each failed trial counts once, under the first cause that applies: misread (the written plan does not "
             "lead to the goal, by the oracle's parser), verifier passed a miss (a commit it accepted failed its "
             "sub-plan by simulator truth), false claim of completion, no candidate passed (a round fell back), out "
             "of steps (a right plan the actions did not finish), crashed. A policy that writes no plan (the twin) is "
             "never counted as a misread: its failures are out of steps. Shares are of the failures. Out of "
             "distribution, a misread points at the language, out of steps at the actions (unseen views), a "
             "verifier's pass of a miss at the verifier."]
    missing = sum(r.no_trace for r in rows)
    if missing:
        notes.append(f"{missing} failure(s) had no trace on disk: a verifier's pass of a miss could not be seen there.")
    return Table("Why episodes failed", headers, body, set(), notes, left=2)


def cause_csv(rows: list[CauseRow]) -> str:
    return to_csv(["suite", "method", "config_hash", "trials", "failures", *[c.replace(" ", "_") for c in CAUSES],
                   "failures_without_trace", "misread_tasks"],
                  [[r.suite, r.method.label, r.method.config_hash, r.trials, r.failures,
                    *[r.counts[c] for c in CAUSES], r.no_trace, ";".join(map(str, r.misread_tasks))] for r in rows])


# ---- the passes SEAL acted on -----------------------------------------------------------------------
@dataclass
class PassRow:
    suite: str
    method: MethodInfo
    trials: int
    passes: int  # audited commits the verifier had passed
    held: int  # of those, sub-plans that held by simulator truth
    no_trace: int  # trials whose trace was not on disk
    by_kind: dict  # sub-plan kind -> (passes, held)


def pass_rows(data: ReportData) -> list[PassRow]:
    """Per suite and SEAL configuration, over every trial (solved or not): how many of the passes the
    loop committed held, in all and per kind of sub-plan."""
    out = []
    for suite in data.suites:
        for m in data.methods_in(suite):
            if m.method != "seal":
                continue
            rows = [r for r in data.rows if r.suite == suite and r.config_hash == m.config_hash]
            traced = [c for c in (_commits(data, r) for r in rows) if c is not None]
            audited = [c for commits in traced for c in commits if c.passed and c.held is not None]
            by_kind = {kind: (len(of), sum(c.held for c in of)) for kind in KINDS
                       if (of := [c for c in audited if c.kind == kind])}
            out.append(PassRow(suite, m, len(rows), len(audited), sum(c.held for c in audited),
                               len(rows) - len(traced), by_kind))
    return out


def _precision(held: int, passes: int) -> str:
    if not passes:
        return "-"
    low, high = wilson(held, passes)
    return f"{held / passes:.3f} [{low:.3f}, {high:.3f}]"


def pass_display(rows: list[PassRow]) -> Table:
    def counts(r: PassRow) -> list[str]:
        if r.no_trace == r.trials:  # nothing to count: a 0 here would read as a verifier that never passed
            return ["no trace"] * 2 + ["-"]
        return [str(r.passes), str(r.held), _precision(r.held, r.passes)]

    body = [[r.suite, r.method.label, f"{r.trials - r.no_trace} of {r.trials}" if r.no_trace else str(r.trials),
             *counts(r)] for r in rows]
    notes = ["Every commit of a passing candidate whose sub-plan the simulator audited, in solved and failed trials; "
             "held: its goal atoms held in the committed state. Precision with a Wilson 95% interval. SEAL commits "
             "the first candidate of a round that passes, so a verifier's false passes are selected for: this "
             "precision sits below the same verifier's precision on single cases (`seal bench verifier`). The "
             "audit checks a pick with Held (each finger touches the object), as the oracle does, so the "
             "oracle's passes hold by construction; traces written before 2026-12-05 audited picks with "
             "robosuite's pad check, under which an object carried on a finger's body is not picked."]
    missing = sum(r.no_trace for r in rows)
    if missing:
        notes.append(f"{missing} trial(s) had no trace on disk and are left out.")
    return Table("The passes SEAL committed: how many held", ["Suite", "Method", "trials traced", "committed passes",
                                                              "held", "precision"], body, set(), notes, left=2)


def pass_kind_display(rows: list[PassRow]) -> Table:
    """The table above split by the kind of sub-plan: where a verifier's false passes sit."""
    kinds = [k for k in KINDS if any(k in r.by_kind for r in rows)]

    def cell(r: PassRow, kind: str) -> str:
        passes, held = r.by_kind.get(kind, (0, 0))
        return f"{held}/{passes} = {_precision(held, passes)}" if passes else "-"

    body = [[r.suite, r.method.label] + [cell(r, k) for k in kinds] for r in rows if r.passes]
    notes = ["Held / committed passes per kind of sub-plan, with the precision and its Wilson 95% interval. The kind "
             "is read from the sub-plan's first verb (pick, place, open, close, turn; anything else is other)."]
    return Table("The passes SEAL committed, by kind of sub-plan", ["Suite", "Method"] + kinds, body, set(), notes,
                 left=2)


def pass_csv(rows: list[PassRow]) -> str:
    return to_csv(["suite", "method", "config_hash", "trials", "committed_passes", "held", "trials_without_trace"],
                  [[r.suite, r.method.label, r.method.config_hash, r.trials, r.passes, r.held, r.no_trace]
                   for r in rows])


def pass_kind_csv(rows: list[PassRow]) -> str:
    return to_csv(["suite", "method", "config_hash", "kind", "committed_passes", "held"],
                  [[r.suite, r.method.label, r.method.config_hash, kind, passes, held]
                   for r in rows for kind, (passes, held) in r.by_kind.items()])


# ---- the candidates SEAL sampled ---------------------------------------------------------------------
@dataclass
class CandidateRow:
    suite: str
    method: MethodInfo
    trials: int  # trials with a trace
    by_kind: dict  # sub-plan kind -> (candidates judged, passed)

    @property
    def totals(self) -> tuple[int, int]:
        return sum(n for n, _ in self.by_kind.values()), sum(p for _, p in self.by_kind.values())


def _candidates(data: ReportData, row: TrialRow) -> dict | None:
    """Sub-plan kind -> (candidates with a verdict, passed) in one trial's trace; None: no trace."""
    trace = data.resolve(row.trace_path)
    if trace is None:
        return None
    out: dict = {}
    for subplan, event in _trace_events(trace, "candidate"):
        if isinstance(verdict := event.get("verdict"), dict):
            n, p = out.get(kind := subplan_kind(subplan), (0, 0))
            out[kind] = (n + 1, p + (verdict.get("success") is True))
    return out


def candidate_rows(data: ReportData) -> list[CandidateRow]:
    """Per suite and SEAL configuration: of the candidates its verifier judged, how many passed, per kind
    of sub-plan. With the oracle a pass is the sub-plan achieved by simulator truth, so the rate is how
    often one sampled action sequence does what its own plan says: a round of K candidates finds none
    with probability (1 - rate)^K."""
    out = []
    for suite in data.suites:
        for m in data.methods_in(suite):
            if m.method != "seal":
                continue
            traced = [c for c in (_candidates(data, r) for r in data.rows
                                  if r.suite == suite and r.config_hash == m.config_hash) if c is not None]
            by_kind: dict = {}
            for c in traced:
                for kind, (n, p) in c.items():
                    a, b = by_kind.get(kind, (0, 0))
                    by_kind[kind] = (a + n, b + p)
            if by_kind:
                out.append(CandidateRow(suite, m, len(traced), {k: by_kind[k] for k in KINDS if k in by_kind}))
    return out


def candidate_display(rows: list[CandidateRow]) -> Table:
    kinds = [k for k in KINDS if any(k in r.by_kind for r in rows)]

    def cell(n: int, p: int) -> str:
        return f"{p}/{n} = {p / n:.2f}" if n else "-"

    body = [[r.suite, r.method.label, str(r.trials), cell(*r.totals)]
            + [cell(*r.by_kind.get(k, (0, 0))) for k in kinds] for r in rows]
    notes = ["Passed / judged candidates, over every round of every traced trial, in all and per kind of sub-plan "
             "(the sub-plan's first verb). With the oracle a pass is the sub-plan achieved by simulator truth: the "
             "rate is how often one action sequence sampled by the policy does what its own plan says, and a round "
             "of K = 10 finds none with probability (1 - rate)^10. With another verifier it is that verifier's "
             "acceptance rate. Rounds re-sampled after a failed round count again, so hard sub-plans weigh more."]
    return Table("The candidates SEAL sampled: how many passed", ["Suite", "Method", "traced trials", "all"] + kinds,
                 body, set(), notes, left=2)


def candidate_csv(rows: list[CandidateRow]) -> str:
    return to_csv(["suite", "method", "config_hash", "traced_trials", "kind", "candidates", "passed"],
                  [[r.suite, r.method.label, r.method.config_hash, r.trials, kind, n, p]
                   for r in rows for kind, (n, p) in r.by_kind.items()])
