"""The report's tables: computed once as numbers, then shown as Markdown, HTML or CSV.

Success tables follow the paper's layout (a suite per table, tasks as rows, methods as columns,
an average row, the best method per row in bold), with a Wilson 95% interval in every cell and
the paper's own numbers in extra columns where the paper reports that suite.
"""

from __future__ import annotations

import csv
import io
import math
from collections import Counter
from dataclasses import dataclass, field

from seal.report.data import Cell, MethodInfo, ReportData, succeeded
from seal.report.paper import PAPER_NAMES, TABLES, PaperResults
from seal.report.stats import PairedDifference, paired_difference, wilson


# ---- display model shared by Markdown and HTML ---------------------------------------------------
@dataclass
class Table:
    """Rows of strings; ``bold`` holds (row, column) positions to emphasise."""

    title: str
    headers: list[str]
    rows: list[list[str]]
    bold: set[tuple[int, int]] = field(default_factory=set)
    notes: list[str] = field(default_factory=list)
    left: int = 2  # leading text columns (left-aligned); the rest are numbers


def to_markdown(t: Table) -> str:
    def esc(s: str) -> str:  # a '|' inside a cell would end it
        return s.replace("\\", "\\\\").replace("|", "\\|").replace("\n", " ")

    lines = [f"### {t.title}", ""]
    if t.rows:  # a table with a header and no rows reads as broken; the notes say why it is empty
        lines += ["| " + " | ".join(esc(h) for h in t.headers) + " |",
                  "|" + "|".join("---" if i < t.left else "---:" for i in range(len(t.headers))) + "|"]
    for i, row in enumerate(t.rows):
        cells = [f"**{esc(c)}**" if (i, j) in t.bold and c else esc(c) for j, c in enumerate(row)]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [""] + [f"{n}  " for n in t.notes]
    return "\n".join(lines).rstrip() + "\n"


def to_csv(headers: list[str], rows: list[list]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(headers)
    w.writerows([["" if isinstance(v, float) and math.isnan(v) else v for v in row] for row in rows])
    return buf.getvalue()


def pct(x: float, digits: int = 1) -> str:
    return "–" if x is None or math.isnan(x) else f"{100 * x:.{digits}f}"


# ---- success tables ----------------------------------------------------------------------------
@dataclass
class SuccessTable:
    suite: str
    methods: list[MethodInfo]
    paper_methods: list[str]  # paper columns, e.g. ["pi0_reason", "seal"]
    training: str
    tasks: list[int]
    # task id, "average" or (while some column is partial) "common" -> one Cell per method
    cells: dict[int | str, list[Cell]]
    paper: dict[int | str, list[float | None]]  # same keys -> percent per paper column
    instructions: dict[int, str]

    @property
    def keys(self) -> list[int | str]:
        return [*self.tasks, "average", *(["common"] if "common" in self.cells else [])]

    def best(self, key) -> set[int]:
        """Columns with the highest success rate in a row (ties all count)."""
        rates = [c.rate for c in self.cells[key]]
        valid = [r for r in rates if not math.isnan(r)]
        if not valid:
            return set()
        top = max(valid)
        return {j for j, r in enumerate(rates) if not math.isnan(r) and r == top}


def success_table(data: ReportData, suite: str, paper: PaperResults, training: str) -> SuccessTable:
    methods = data.methods_in(suite)
    tasks = data.tasks(suite)
    paper_methods: list[str] = []
    if paper.has_suite(suite, training):
        for m in methods:
            pm = m.paper_method
            if pm and pm not in paper_methods:
                paper_methods.append(pm)
    cells = {t: [data.cell(suite, t, m.config_hash) for m in methods] for t in tasks}
    cells["average"] = [data.pooled(m.config_hash, suite) for m in methods]
    if len({c.n for c in cells["average"]}) > 1:  # a partial column: also pool only what every column ran
        common = data.outcomes([m.config_hash for m in methods], suite)
        cells["common"] = [Cell(n=len(common), successes=sum(o[j] for o in common)) for j in range(len(methods))]
    prates = {t: [paper.rate(suite, training, t, pm) for pm in paper_methods] for t in tasks}
    # The paper's average over the same tasks we ran, from its per-task rows (its printed
    # averages do not always match its own rows; see docs/reports.md).
    prates["average"] = [_mean([prates[t][j] for t in tasks]) for j in range(len(paper_methods))]
    if "common" in cells:
        prates["common"] = [None] * len(paper_methods)
    return SuccessTable(suite, methods, paper_methods, training, tasks, cells, prates,
                        {t: data.instruction(suite, t) for t in tasks})


def _mean(values: list[float | None]) -> float | None:
    got = [v for v in values if v is not None]
    return sum(got) / len(got) if got else None


def usual_trials(st: SuccessTable) -> int:
    """The most common trial count of a task cell: cells with another count say n=..."""
    counts = Counter(c.n for key in st.tasks for c in st.cells[key] if c.n)
    return counts.most_common(1)[0][0] if counts else 0


COMMON_NOTE = ("Some column is partial, so its Average pools other tasks than its neighbours': "
               "'Average, common starts' pools only the (task, trial) starts every column ran; compare that row.")


def row_name(key: int | str) -> str:
    return {"average": "Average", "common": "Average, common starts"}.get(key, str(key))


def success_display(st: SuccessTable) -> Table:
    usual = usual_trials(st)
    headers = ["Task", "Instruction", *[m.label for m in st.methods],
               *[f"paper {PAPER_NAMES.get(pm, pm)}" for pm in st.paper_methods]]
    rows, bold = [], set()
    for i, key in enumerate(st.keys):
        row = [row_name(key), st.instructions.get(key, "") if isinstance(key, int) else ""]
        for c in st.cells[key]:
            row.append(cell_text(c, usual if isinstance(key, int) else None))
        row += ["–" if v is None else f"{v:.1f}" for v in st.paper[key]]
        rows.append(row)
        bold |= {(i, 2 + j) for j in st.best(key)}
    notes = [(f"Success in percent with a Wilson 95% interval; {usual} trials per cell unless marked "
             "(n=...). Error trials count as failures (marked err). Average = all trials of the suite pooled.")]
    if "common" in st.cells:
        notes.append(COMMON_NOTE)
    if st.paper_methods:
        notes.append(f"Paper columns: {TABLES.get(st.suite, 'the paper')}, trained on {st.training}; "
                     "their average is the mean of the paper's per-task rows for the tasks shown.")
    return Table(f"{st.suite}: success rate (%)", headers, rows, bold, notes)


def cell_text(c: Cell, usual: int | None) -> str:
    if c.n == 0:
        return "–"
    lo, hi = c.ci
    text = f"{pct(c.rate)} [{pct(lo)}, {pct(hi)}]"
    extra = [f"n={c.n}"] if usual is not None and c.n != usual else []
    if c.errors:
        extra.append(f"{c.errors} err")
    return text + (f" ({', '.join(extra)})" if extra else "")


def success_csv(st: SuccessTable) -> str:
    headers = ["task", "instruction"]
    for m in st.methods:
        headers += [f"{m.label} success_pct", f"{m.label} ci_low", f"{m.label} ci_high", f"{m.label} n",
                    f"{m.label} errors", f"{m.label} config_hash"]
    headers += [f"paper {pm}" for pm in st.paper_methods]
    rows = []
    for key in st.keys:
        row = [key, st.instructions.get(key, "") if isinstance(key, int) else ""]
        for m, c in zip(st.methods, st.cells[key]):
            lo, hi = c.ci
            row += [num(100 * c.rate), num(100 * lo), num(100 * hi), c.n, c.errors, m.config_hash]
        row += ["" if v is None else v for v in st.paper[key]]
        rows.append(row)
    return to_csv(headers, rows)


def num(x: float, digits: int = 2):
    return "" if math.isnan(x) else round(x, digits)


def long_csv(data: ReportData, tables: list[SuccessTable]) -> str:
    """One row per (suite, task, method): the easiest shape for other tools."""
    rows = []
    for st in tables:
        for key in st.keys:
            for j, (m, c) in enumerate(zip(st.methods, st.cells[key])):
                pm = m.paper_method if m.paper_method in st.paper_methods else None
                pv = st.paper[key][st.paper_methods.index(pm)] if pm else None
                lo, hi = c.ci
                rows.append([st.suite, key, m.label, m.config_hash, c.n, c.successes, c.errors, c.sim_errors,
                             num(100 * c.rate), num(100 * lo), num(100 * hi), pm or "", "" if pv is None else pv])
    return to_csv(["suite", "task", "method", "config_hash", "trials", "successes", "errors", "sim_errors",
                   "success_pct", "ci_low", "ci_high", "paper_method", "paper_pct"], rows)


# ---- paired differences -----------------------------------------------------------------------
@dataclass
class PairedRow:
    suite: str  # or "all"
    a: MethodInfo
    b: MethodInfo
    result: PairedDifference


def paired_rows(data: ReportData) -> list[PairedRow]:
    """Every later method against every earlier one (so 'seal - base'), per suite and overall."""
    out = []
    for suite in [*data.suites, None]:
        methods = data.methods_in(suite)
        for i, b in enumerate(methods):
            for a in methods[i + 1:]:
                pairs = data.pairs(a.config_hash, b.config_hash, suite)
                if pairs:
                    out.append(PairedRow(suite or "all", a, b, paired_difference(pairs)))
    if len(data.suites) == 1:  # "all" would repeat the one suite
        out = [r for r in out if r.suite != "all"]
    return out


def paired_display(rows: list[PairedRow]) -> Table:
    headers = ["Suite", "A", "B", "paired trials", "A only", "B only", "A − B (pp)", "95% CI (pp)", "McNemar p"]
    body, bold = [], set()
    for i, r in enumerate(rows):
        d = r.result
        body.append([r.suite, r.a.label, r.b.label, str(d.n), str(d.only_a), str(d.only_b), f"{100 * d.diff:+.1f}",
                     f"[{100 * d.ci[0]:+.1f}, {100 * d.ci[1]:+.1f}]", f"{d.p_value:.3g}"])
        if d.ci[0] > 0 or d.ci[1] < 0:
            bold.add((i, 6))
    notes = [("Paired on (suite, task, trial): the same init state and seed for both methods. "
             "CI: Newcombe's hybrid score interval for paired proportions; p: exact McNemar test on the "
             "trials where exactly one method succeeded. Bold: the interval excludes 0.")]
    return Table("Paired differences (A − B, percentage points)", headers, body, bold, notes, left=3)


def paired_csv(rows: list[PairedRow]) -> str:
    return to_csv(["suite", "a", "b", "a_config_hash", "b_config_hash", "paired_trials", "both", "a_only", "b_only",
                   "neither", "diff_pp", "ci_low_pp", "ci_high_pp", "mcnemar_p"],
                  [[r.suite, r.a.label, r.b.label, r.a.config_hash, r.b.config_hash, r.result.n, r.result.both,
                    r.result.only_a, r.result.only_b, r.result.neither, num(100 * r.result.diff), num(100 * r.result.ci[0]),
                    num(100 * r.result.ci[1]), round(r.result.p_value, 6)] for r in rows])


# ---- runtime ------------------------------------------------------------------------------------
@dataclass
class RuntimeRow:
    method: MethodInfo
    trials: int
    steps: int  # executed env steps, all trials
    wall_s: float
    step_s: float
    verify_wait_s: float
    verifier_calls: int
    input_tokens: int
    output_tokens: int
    cost_usd: float
    fallbacks: int = 0  # sub-plans where no candidate passed and the fallback chose
    verifier_errors: int = 0  # verifications with no answer
    unverified_trials: int = 0  # trials whose verifier never answered in most of their rounds

    def per_trial(self, total: float) -> float:
        return total / self.trials if self.trials else math.nan

    @property
    def wall_per_step_s(self) -> float:
        """Ratio of totals (not a mean of ratios), so short failed episodes do not dominate."""
        return self.wall_s / self.steps if self.steps else math.nan


def runtime_rows(data: ReportData) -> list[RuntimeRow]:
    out = []
    for m in data.methods:
        rs = [r for r in data.rows if r.config_hash == m.config_hash]
        out.append(RuntimeRow(m, len(rs), sum(r.steps for r in rs), sum(r.wall_s for r in rs),
                              sum(r.step_s for r in rs), sum(r.verify_wait_s for r in rs),
                              sum(r.verifier_calls for r in rs), sum(r.input_tokens for r in rs),
                              sum(r.output_tokens for r in rs), sum(r.cost_usd for r in rs),
                              sum(r.fallbacks for r in rs), sum(r.verifier_errors for r in rs),
                              sum(r.verifier_unavailable for r in rs)))
    return out


def runtime_display(rows: list[RuntimeRow]) -> Table:
    headers = ["Method", "K", "trials", "wall s / trial", "executed steps / trial", "wall ms / executed step",
               "sim s / trial", "verify wait s / trial", "verifier calls / trial", "tokens in / trial",
               "tokens out / trial", "cost $ / trial", "cost $ total", "fallbacks / trial",
               "verifier errors", "trials mostly unverified"]
    body = [[r.method.label, str(r.method.k), str(r.trials), f"{r.per_trial(r.wall_s):.2f}",
             f"{r.per_trial(r.steps):.1f}", _fmt(1000 * r.wall_per_step_s, 1), f"{r.per_trial(r.step_s):.2f}",
             f"{r.per_trial(r.verify_wait_s):.2f}", f"{r.per_trial(r.verifier_calls):.1f}",
             f"{r.per_trial(r.input_tokens):.0f}", f"{r.per_trial(r.output_tokens):.0f}",
             f"{r.per_trial(r.cost_usd):.4f}", f"{r.cost_usd:.4f}", f"{r.per_trial(r.fallbacks):.2f}",
             str(r.verifier_errors), str(r.unverified_trials)] for r in rows]
    notes = [("All trials of a configuration, error trials included (they cost time too). Per executed "
             "step = total wall time / total executed env steps. sim = time stepping the simulator for "
             "candidates; verify wait = time blocked on verdicts. fallbacks = sub-plans where no candidate "
             "passed and the best-scored (else the first) candidate was executed; verifier errors = "
             "verifications that got no answer after every retry; trials mostly unverified = trials where, "
             "in more than half of the sampling rounds that asked the verifier, no verification got an answer.")]
    return Table("Runtime per method configuration", headers, body, set(), notes, left=1)


def runtime_csv(rows: list[RuntimeRow]) -> str:
    return to_csv(["method", "config_hash", "k", "trials", "executed_steps", "wall_s_per_trial",
                   "wall_s_per_executed_step", "sim_s_per_trial", "verify_wait_s_per_trial",
                   "verifier_calls_per_trial", "input_tokens_per_trial", "output_tokens_per_trial",
                   "cost_usd_per_trial", "cost_usd_total", "fallbacks_per_trial", "verifier_errors",
                   "trials_mostly_unverified"],
                  [[r.method.label, r.method.config_hash, r.method.k, r.trials, r.steps,
                    num(r.per_trial(r.wall_s), 3), num(r.wall_per_step_s, 5), num(r.per_trial(r.step_s), 3),
                    num(r.per_trial(r.verify_wait_s), 3), num(r.per_trial(r.verifier_calls), 2),
                    num(r.per_trial(r.input_tokens), 1), num(r.per_trial(r.output_tokens), 1),
                    num(r.per_trial(r.cost_usd), 6), round(r.cost_usd, 6), num(r.per_trial(r.fallbacks), 3),
                    r.verifier_errors, r.unverified_trials] for r in rows])


# ---- alignment ------------------------------------------------------------------------------------
@dataclass
class AlignmentRow:
    """The reasoning-action alignment of one method configuration on one suite: of the sub-plans it
    committed (and the oracle could ground), the share whose executed chunks achieved the sub-plan."""

    suite: str
    method: MethodInfo
    trials: int
    audited: int
    aligned: int

    @property
    def rate(self) -> float:
        return self.aligned / self.audited if self.audited else math.nan


def alignment_rows(data: ReportData) -> list[AlignmentRow]:
    """Per suite: out of distribution, the same plans with a lower rate say the actions stopped
    following the reasoning."""
    out = []
    for suite in data.suites:
        for m in data.methods_in(suite):
            rs = [r for r in data.rows if r.suite == suite and r.config_hash == m.config_hash]
            out.append(AlignmentRow(suite, m, len(rs), sum(r.subplans_audited for r in rs),
                                    sum(r.subplans_aligned for r in rs)))
    return out


def alignment_display(rows: list[AlignmentRow]) -> Table:
    headers = ["Suite", "Method", "K", "trials", "sub-plans audited", "achieved", "alignment rate", "95% CI"]
    body = []
    for r in rows:
        lo, hi = wilson(r.aligned, r.audited) if r.audited else (math.nan, math.nan)
        body.append([r.suite, r.method.label, str(r.method.k), str(r.trials), str(r.audited), str(r.aligned),
                     _fmt(100 * r.rate, 1) + ("%" if r.audited else ""),
                     f"{_fmt(100 * lo, 0)}–{_fmt(100 * hi, 0)}%" if r.audited else "–"])
    notes = [("After every commit, the oracle grounds the sub-plan the policy wrote to goal atoms and checks them "
              "in the committed state: a sub-plan is achieved when its executed chunks did what it says. The audit "
              "runs for every method and never influences a decision. Sub-plans the oracle cannot ground, and "
              "policies that write none (the non-reasoning twin), are not counted.")]
    return Table("Reasoning-action alignment (committed sub-plans achieved, by simulator truth)", headers, body,
                 set(), notes, left=2)


def alignment_csv(rows: list[AlignmentRow]) -> str:
    return to_csv(["suite", "method", "config_hash", "k", "trials", "subplans_audited", "subplans_aligned",
                   "alignment_rate"],
                  [[r.suite, r.method.label, r.method.config_hash, r.method.k, r.trials, r.audited, r.aligned,
                    num(r.rate, 4)] for r in rows])


def _fmt(x: float, digits: int) -> str:
    return "–" if math.isnan(x) else f"{x:.{digits}f}"


# ---- how episodes ended ----------------------------------------------------------------------------
ENDINGS = ("goal_holds", "policy_finished", "step_limit", "idle", "sim_error", "error", "not recorded")
_ENDING_NOTES = {
    "goal_holds": "the task's goal held after a commit",
    "policy_finished": "the policy wrote that the task is done (goal not holding when it is a failure)",
    "step_limit": "the episode used its step budget",
    "idle": "the policy kept switching to reasoning without acting",
    "sim_error": "every candidate of a sub-plan broke the simulator",
    "error": "the trial crashed (status 'error')",
    "not recorded": "rows stored before the results schema kept it, with no trace that says",
}


@dataclass
class EndingRow:
    """How one method configuration's episodes stopped: counts per ``ended_by`` value."""

    method: MethodInfo
    trials: int
    counts: dict  # ending -> (all episodes, failed episodes)


def ending_rows(data: ReportData) -> list[EndingRow]:
    out = []
    for m in data.methods:
        rows = [r for r in data.rows if r.config_hash == m.config_hash]
        counts = {e: [0, 0] for e in ENDINGS}
        for r in rows:
            end = counts.setdefault(data.ended_by(r), [0, 0])  # a reason this report does not know yet still counts
            end[0] += 1
            end[1] += not succeeded(r)
        out.append(EndingRow(m, len(rows), {e: tuple(v) for e, v in counts.items()}))
    return out


def ending_display(rows: list[EndingRow]) -> Table:
    known = list(ENDINGS) + sorted({e for r in rows for e in r.counts} - set(ENDINGS))
    used = [e for e in known if any(r.counts.get(e, (0, 0))[0] for r in rows)]
    headers = ["Method", "trials"] + used
    body = [[r.method.label, str(r.trials)] + [_ending_cell(*r.counts.get(e, (0, 0))) for e in used] for r in rows]
    notes = ["Each cell: episodes that ended this way (of them, failures in brackets). A failure that ended "
             "before its step budget is one the policy gave up on; the next table says which of those claims "
             "a verifier caught."] + [f"{e}: {_ENDING_NOTES[e]}." for e in used if e in _ENDING_NOTES]
    return Table("How episodes ended", headers, body, set(), notes, left=1)


def _ending_cell(n: int, failed: int) -> str:
    return f"{n} ({failed})" if n else "0"


def ending_csv(rows: list[EndingRow]) -> str:
    return to_csv(["method", "config_hash", "trials", "ended_by", "episodes", "failed"],
                  [[r.method.label, r.method.config_hash, r.trials, e, *n] for r in rows for e, n in r.counts.items()
                   if n[0]])


@dataclass
class CompletionRow:
    """What came of one method configuration's claims that the task was done.

    The goal is checked after every commit and ends the episode when it holds, so whenever a policy
    writes that the task is done, it is not: every such claim is false. Without a check, an episode
    ends at its first claim (``claimed`` is what the claims would cost); a method that verifies them
    sends the policy back on a refusal, and loses only the episodes it let end (``ended``)."""

    method: MethodInfo
    trials: int
    claimed: int  # episodes with at least one false claim of completion
    refused: int  # claims the verifier refused, summed over episodes
    ended: int  # episodes that ended on a false claim (accepted, or the verifier could not tell)
    rescued: int  # episodes with a refused claim that went on to succeed


def completion_rows(data: ReportData) -> list[CompletionRow]:
    out = []
    for m in data.methods:
        rows = [r for r in data.rows if r.config_hash == m.config_hash]
        ended = [not succeeded(r) and data.ended_by(r) == "policy_finished" for r in rows]
        out.append(CompletionRow(
            m, len(rows),
            claimed=sum(e or r.done_refusals > 0 for r, e in zip(rows, ended)),
            refused=sum(r.done_refusals for r in rows),
            ended=sum(ended),
            rescued=sum(r.done_refusals > 0 and succeeded(r) for r in rows)))
    return out


def completion_display(rows: list[CompletionRow]) -> Table:
    def share(n: int, of: int) -> str:
        return f"{n} ({100 * n / of:.0f}%)" if of else "0"

    headers = ["Method", "trials", "episodes with a false claim", "claims refused", "ended on a false claim",
               "refused, then solved"]
    body = [[r.method.label, str(r.trials), share(r.claimed, r.trials), str(r.refused), share(r.ended, r.trials),
             str(r.rescued)] for r in rows]
    notes = ["The goal is checked after every commit and ends the episode when it holds, so a policy that "
             "writes that the task is done is always wrong. Without a check, each episode with a false claim "
             "ends at its first one, failed; a method that verifies claims sends the policy back on a refusal "
             "and loses only the episodes that ended on a claim it accepted or could not judge."]
    return Table("Declared completions (the policy wrote that the task is done)", headers, body, set(), notes, left=1)


def completion_csv(rows: list[CompletionRow]) -> str:
    return to_csv(["method", "config_hash", "trials", "episodes_with_false_claim", "claims_refused",
                   "ended_on_false_claim", "refused_then_solved"],
                  [[r.method.label, r.method.config_hash, r.trials, r.claimed, r.refused, r.ended, r.rescued]
                   for r in rows])


# ---- error trials ------------------------------------------------------------------------------
def error_display(data: ReportData) -> Table:
    body = [[data.label_of(r), r.suite, str(r.task), str(r.trial), r.worker, last_line(r.error)] for r in data.errors()]
    notes = [] if body else ["No trial crashed."]
    return Table("Error trials (counted as failures)", ["Method", "Suite", "Task", "Trial", "Worker", "Error"],
                 body, set(), notes, left=6)


def error_csv(data: ReportData) -> str:
    return to_csv(["method", "config_hash", "suite", "task", "trial", "worker", "error"],
                  [[data.label_of(r), r.config_hash, r.suite, r.task, r.trial, r.worker, r.error] for r in data.errors()])


# ---- verifier errors ---------------------------------------------------------------------------
def verifier_display(data: ReportData) -> Table:
    body = [[data.label_of(r), r.suite, str(r.task), str(r.trial), str(r.verifier_calls), str(r.verifier_errors),
             "yes" if r.verifier_unavailable else "no"] for r in data.verifier_trouble()]
    notes = [data.verifier_warning()] if body else ["Every verification got an answer."]
    return Table("Verifier errors", ["Method", "Suite", "Task", "Trial", "verifier calls", "no answer",
                                     "mostly unverified"], body, set(), notes, left=4)


def verifier_csv(data: ReportData) -> str:
    return to_csv(["method", "config_hash", "suite", "task", "trial", "verifier_calls", "verifier_errors",
                   "verifier_unavailable"],
                  [[data.label_of(r), r.config_hash, r.suite, r.task, r.trial, r.verifier_calls, r.verifier_errors,
                    int(r.verifier_unavailable)] for r in data.verifier_trouble()])


def last_line(traceback_text: str) -> str:
    lines = [ln for ln in traceback_text.strip().splitlines() if ln.strip()]
    return lines[-1].strip() if lines else ""
