"""The paper's generalization tables: Table VII (the four out-of-distribution suites) and Table VIII
(behavior composition), with our numbers beside the paper's.

One table per suite: tasks as rows and an Average row; our methods as columns in the paper's
column order (pi0, pi0+V-GPS, pi0-reason, SEAL), each followed by the paper's figure for it; then
one column per SEAL configuration with the paired difference to its own base (the same policy and
settings, unsteered), per task and, in the Average row, over the suite.
"""

from __future__ import annotations

from dataclasses import dataclass

from seal.report.data import MethodInfo, ReportData
from seal.report.paper import PAPER_NAMES, PAPER_ORDER, TABLES, PaperResults
from seal.report.stats import PairedDifference, paired_difference
from seal.report.tables import (COMMON_NOTE, SuccessTable, Table, cell_text, num, row_name, success_table, to_csv,
                                 usual_trials)
from seal.verify import VERIFIERS

OOD_SUITES = ("lang_rephrase", "lang_object_property", "visual_scene", "visual_viewpoint")
SECTIONS = (("Table II layout: in distribution (LIBERO-10)", ("libero_10",)),
            ("Table VII layout: out-of-distribution suites", OOD_SUITES),
            ("Table VIII layout: behavior composition", ("composition",)))
# Settings only a steering method has: without them (and as method "base") a SEAL configuration is
# the unsteered configuration it is compared with.
# what tells one verifier from another: its name and every option some verifier plug-in declares (a
# learned verifier's threshold, a VLM's model, injected error rates)
VERIFIER_KEYS = frozenset({"verifier"} | VERIFIERS.option_names())
STEERING_ONLY = frozenset({"k", "rounds", "check_every", "pick", "verify_order", "done_check",
                           "subplan_ref"}) | VERIFIER_KEYS


@dataclass
class Difference:
    """A SEAL configuration minus its base on the same trials: per task, and "average" for the suite."""

    seal: MethodInfo
    base: MethodInfo
    by_key: dict[int | str, PairedDifference]


@dataclass
class PaperLayout:
    table: SuccessTable  # methods in the paper's column order
    differences: list[Difference]

    @property
    def suite(self) -> str:
        return self.table.suite


def base_of(seal: MethodInfo, methods: list[MethodInfo]) -> MethodInfo | None:
    """The unsteered configuration a SEAL configuration is compared with, if the report has it."""
    if seal.method != "seal":
        return None
    want = {k: v for k, v in seal.config.items() if k not in STEERING_ONLY} | {"method": "base"}
    return next((m for m in methods if m.config == want), None)


def paper_layout(data: ReportData, suite: str, paper: PaperResults, training: str) -> PaperLayout:
    table = _in_paper_order(success_table(data, suite, paper, training))
    differences = []
    for seal in table.methods:
        base = base_of(seal, table.methods)
        if base is None:
            continue
        by_key = {t: paired_difference(data.pairs(seal.config_hash, base.config_hash, suite, t)) for t in table.tasks}
        by_key["average"] = paired_difference(data.pairs(seal.config_hash, base.config_hash, suite))
        differences.append(Difference(seal, base, by_key))
    return PaperLayout(table, differences)


def _in_paper_order(st: SuccessTable) -> SuccessTable:
    """The same table with methods and paper columns in the paper's order (ours without a paper
    counterpart last); the order among our methods is otherwise kept."""
    def rank(pm: str | None) -> int:
        return PAPER_ORDER.index(pm) if pm in PAPER_ORDER else len(PAPER_ORDER)

    order = sorted(range(len(st.methods)), key=lambda j: rank(st.methods[j].paper_method))
    porder = sorted(range(len(st.paper_methods)), key=lambda j: rank(st.paper_methods[j]))
    return SuccessTable(st.suite, [st.methods[j] for j in order], [st.paper_methods[j] for j in porder], st.training,
                        st.tasks, {k: [cells[j] for j in order] for k, cells in st.cells.items()},
                        {k: [vals[j] for j in porder] for k, vals in st.paper.items()}, st.instructions)


def _columns(st: SuccessTable) -> list[tuple[str, int]]:
    """("ours", method index) and ("paper", paper index) in display order: each paper figure right
    after the last of our methods it stands beside."""
    out = []
    for j, m in enumerate(st.methods):
        out.append(("ours", j))
        following = st.methods[j + 1].paper_method if j + 1 < len(st.methods) else None
        if m.paper_method in st.paper_methods and following != m.paper_method:
            out.append(("paper", st.paper_methods.index(m.paper_method)))
    return out


def layout_display(layout: PaperLayout) -> Table:
    st = layout.table
    columns = _columns(st)
    headers = ["Task"] + [st.methods[j].label if kind == "ours" else f"paper {_paper_name(st.paper_methods[j])}"
                          for kind, j in columns]
    headers += [f"{d.seal.label} − {d.base.label} (pp)" for d in layout.differences]
    usual = usual_trials(st)
    rows, bold = [], set()
    for i, key in enumerate(st.keys):
        row = [row_name(key)]
        best = st.best(key)
        for col, (kind, j) in enumerate(columns, start=1):
            if kind == "ours":
                row.append(cell_text(st.cells[key][j], usual if isinstance(key, int) else None))
                if j in best:
                    bold.add((i, col))
            else:
                value = st.paper[key][j]
                row.append("–" if value is None else f"{value:.1f}")
        for d in layout.differences:
            diff = d.by_key.get(key)
            if diff is None:  # the common-starts row: the Average row's differences are paired already
                row.append("")
                continue
            row.append(difference_text(diff))
            if diff.n and (diff.ci[0] > 0 or diff.ci[1] < 0):
                bold.add((i, len(row) - 1))
        rows.append(row)
    return Table(f"{st.suite}: ours beside the paper ({TABLES.get(st.suite, 'paper')} layout)", headers, rows, bold,
                 _notes(layout, usual), left=1)


def _paper_name(paper_method: str) -> str:
    return PAPER_NAMES.get(paper_method, paper_method)


def difference_text(d: PairedDifference) -> str:
    """``+40.0 [+5.1, +66.3]``: the paired difference and its 95% interval, in percentage points."""
    if d.n == 0:
        return "–"
    return f"{100 * d.diff:+.1f} [{100 * d.ci[0]:+.1f}, {100 * d.ci[1]:+.1f}]"


def _notes(layout: PaperLayout, usual: int) -> list[str]:
    st = layout.table
    notes = [f"Ours: success in percent with a Wilson 95% interval, {usual} trials per cell unless marked (n=...); "
             "error trials count as failures. Average = all trials of the suite pooled. Bold: the best of our "
             "methods in the row."]
    if st.paper_methods:
        notes.append(f"paper: {TABLES.get(st.suite, 'the paper')}, trained on {st.training}, 50 trials per task; "
                     "its average is the mean of its per-task rows shown.")
    else:
        notes.append(f"The paper reports no {st.suite} figures for the training set {st.training} "
                     "(or none of our methods has a paper counterpart).")
    if layout.differences:
        notes.append("SEAL − base: each SEAL configuration minus the same policy unsteered, paired on the same "
                     "(task, trial) starts and seeds; per task, and over the whole suite in the Average row. "
                     "Interval: Newcombe's paired score interval, 95%; bold where it excludes 0.")
    if "common" in st.cells:
        notes.append(COMMON_NOTE)
    return notes


def layout_sections(data: ReportData, paper: PaperResults, training: str) -> list[tuple[str, list[PaperLayout]]]:
    """The Table VII and VIII sections for the suites this store holds (none when it holds none)."""
    out = []
    for title, suites in SECTIONS:
        layouts = [paper_layout(data, s, paper, training) for s in suites if s in data.suites]
        if layouts:
            out.append((title, layouts))
    return out


def differences_csv(layouts: list[PaperLayout]) -> str:
    """Every SEAL-minus-base difference of the layouts: one row per (suite, task or average, pair)."""
    rows = []
    for layout in layouts:
        for d in layout.differences:
            for key in d.by_key:
                r = d.by_key[key]
                rows.append([layout.suite, key, d.seal.label, d.seal.config_hash, d.base.label, d.base.config_hash,
                             r.n, r.both, r.only_a, r.only_b, r.neither, num(100 * r.diff), num(100 * r.ci[0]),
                             num(100 * r.ci[1]), round(r.p_value, 6)])
    return to_csv(["suite", "task", "seal", "seal_config_hash", "base", "base_config_hash", "paired_trials", "both",
                   "seal_only", "base_only", "neither", "diff_pp", "ci_low_pp", "ci_high_pp", "mcnemar_p"], rows)
