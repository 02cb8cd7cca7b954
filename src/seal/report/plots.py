"""PNG plots with matplotlib's object API (Figure + Agg canvas): no pyplot, so no global figure
state and no display backend is ever touched, which matters in worker processes and on CI."""

from __future__ import annotations

import math
import textwrap
from collections import defaultdict
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from seal.report.data import Cell, ReportData
from seal.report.tables import RuntimeRow, SuccessTable


def _errorbars(cells: list[Cell]) -> tuple[list[float], list[list[float]]]:
    """Heights in percent and matplotlib's asymmetric [below, above] error lengths."""
    heights, below, above = [], [], []
    for c in cells:
        if c.n == 0:
            heights.append(0.0), below.append(0.0), above.append(0.0)
            continue
        lo, hi = c.ci
        heights.append(100 * c.rate)
        below.append(100 * (c.rate - lo))
        above.append(100 * (hi - c.rate))
    return heights, [below, above]


def success_plot(data: ReportData, tables: list[SuccessTable], path: Path) -> Path:
    """Grouped bars: pooled success per suite (groups) and method (bars), Wilson 95% error bars;
    the paper's average for the matching method as a white diamond on the bar."""
    methods = data.methods
    # The legend sits under the axes: method labels are long (every setting that differs is in
    # them) and beside the axes they squeezed a one-suite plot to a sliver.
    entries = len(methods) + 1
    height = 4.2 + 0.22 * entries
    fig = Figure(figsize=(max(7.0, 1.2 * len(tables) * max(1, len(methods)) * 0.6 + 2), height), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    width = 0.8 / max(1, len(methods))
    for j, m in enumerate(methods):
        xs, cells, paper_x, paper_y = [], [], [], []
        for i, st in enumerate(tables):
            if m not in st.methods:
                continue
            x = i - 0.4 + width * (j + 0.5)
            xs.append(x)
            cells.append(st.cells["average"][st.methods.index(m)])
            pm = m.paper_method
            if pm in st.paper_methods and st.paper["average"][st.paper_methods.index(pm)] is not None:
                paper_x.append(x)
                paper_y.append(st.paper["average"][st.paper_methods.index(pm)])
        heights, err = _errorbars(cells)
        ax.bar(xs, heights, width * 0.92, yerr=err, capsize=3, label=m.label)
        # The value above each whisker: a 0% bar has no height to see, and the whisker's top is
        # easy to misread for the bar's.
        for x, h, up in zip(xs, heights, err[1]):
            ax.text(x, h + up + 1.0, f"{h:.0f}", ha="center", va="bottom", fontsize=7)
        if paper_x:
            # White with a black edge: visible both above a bar and inside it.
            ax.scatter(paper_x, paper_y, marker="D", s=30, facecolors="white", edgecolors="black",
                       linewidths=1.2, zorder=3)
    if any(st.paper_methods for st in tables):
        ax.scatter([], [], marker="D", facecolors="white", edgecolors="black", label="paper (same method)")
    ax.set_xticks(range(len(tables)), [st.suite for st in tables], rotation=15)
    ax.set_ylim(0, 108)
    ax.set_ylabel("success (%)")
    ax.set_title("Success per suite (all trials pooled, Wilson 95% CI)")
    ax.grid(axis="y", alpha=0.3)
    # In the figure's bottom strip, not at a fixed offset under the axes: rotated suite names of any
    # length stay above it (an axes-anchored legend covered "lang_object_property").
    fig.legend(*ax.get_legend_handles_labels(), fontsize=8, loc="lower center", ncol=1, frameon=False)
    fig.tight_layout(rect=(0, (0.15 + 0.17 * entries) / height, 1, 1))
    fig.savefig(path)
    return path


def runtime_vs_k_plot(data: ReportData, runtime: list[RuntimeRow], path: Path) -> Path:
    """Method configs grouped by everything but K: wall time per executed step and success vs K."""
    families: dict[str, list[RuntimeRow]] = defaultdict(list)
    for r in runtime:
        families[r.method.family].append(r)
    fig = Figure(figsize=(10, 4), dpi=110)
    FigureCanvasAgg(fig)
    ax_t, ax_s = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    for family, rows in families.items():
        rows = sorted(rows, key=lambda r: r.method.k)
        ks = [r.method.k for r in rows]
        ms = [1000 * r.wall_per_step_s for r in rows]
        keep = [i for i, v in enumerate(ms) if not math.isnan(v)]
        ax_t.plot([ks[i] for i in keep], [ms[i] for i in keep], marker="o", label=family)
        cells = [data.pooled(r.method.config_hash) for r in rows]
        heights, err = _errorbars(cells)
        ax_s.errorbar(ks, heights, yerr=err, marker="o", capsize=3, label=family)
    all_k = sorted({r.method.k for r in runtime})
    top = max((1000 * r.wall_per_step_s for r in runtime if not math.isnan(r.wall_per_step_s)), default=1.0)
    ax_t.set_ylim(0, 1.15 * top)  # room above the highest point so its marker is not cut
    for ax in (ax_t, ax_s):
        ax.set_xlabel("K (candidates per sub-plan)")
        ax.set_xticks(all_k)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    ax_t.set_ylabel("wall ms per executed step")
    ax_t.set_title("Runtime vs K")
    ax_s.set_ylabel("success (%)")
    ax_s.set_ylim(0, 105)
    ax_s.set_title("Success vs K (all suites, Wilson 95% CI)")
    fig.tight_layout()
    fig.savefig(path)
    return path


RUNTIME_STAGES = (("sampling_ms", "sampling (policy)"), ("render_ms", "render (both cameras, K worlds)"),
                  ("predict_ms", "predict (physics, K worlds)"), ("verify_ms", "verify (waiting)"))


def runtime_breakdown_plot(rows: list[dict], path, *, title: str = "") -> Path:
    """Stacked time per executed env step against K, the paper's Fig. 6 layout; the rest of
    ``total_ms`` (sub-plan starts, bookkeeping) is the top, hatched segment."""
    path = Path(path)
    rows = sorted(rows, key=lambda r: r["k"])
    fig = Figure(figsize=(6.4, 4.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    xs = [str(r["k"]) for r in rows]
    bottom = [0.0] * len(rows)
    for key, label in RUNTIME_STAGES:
        vals = [r.get(key, 0.0) for r in rows]
        ax.bar(xs, vals, bottom=bottom, label=label)
        bottom = [b + v for b, v in zip(bottom, vals)]
    rest = [max(r["total_ms"] - b, 0.0) for r, b in zip(rows, bottom)]
    ax.bar(xs, rest, bottom=bottom, label="other", color="white", edgecolor="grey", hatch="//")
    for x, r in zip(xs, rows):
        ax.annotate(f"{r['total_ms']:.0f}", (x, r["total_ms"]), ha="center", va="bottom", fontsize=8)
    ax.set_xlabel("K (candidates per sub-plan)")
    ax.set_ylabel("ms per executed env step")
    ax.set_title(title or "SEAL step time by stage")
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    return path


def rounds_plot(rows: list[dict], path, *, title: str = "On-policy rounds: the reasoning VLA on held-out fresh starts") -> Path:
    """Each held-out figure per logged row (rows from `seal bench vla --round-log`: DAgger rounds and
    variants beside them): closed-loop success with its Wilson 95% interval, on-policy sub-plan
    accuracy, alignment and goal atoms. Markers only: the rows are separate checkpoints and settings,
    not points of one curve."""
    from seal.report.stats import wilson

    fig = Figure(figsize=(7.5, 4.8), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    xs = list(range(len(rows)))
    success = [100 * r["rollout_success"] for r in rows]
    cis = [wilson(round(r["rollout_success"] * r["episodes"]), r["episodes"]) for r in rows]
    ax.errorbar(xs, success, yerr=[[s - 100 * lo for s, (lo, _) in zip(success, cis)],
                                   [100 * hi - s for s, (_, hi) in zip(success, cis)]],
                marker="o", linestyle="none", capsize=4, label="success alone (Wilson 95%)")
    for key, label, marker in (("onpolicy_subplan_accuracy", "on-policy sub-plan accuracy", "s"),
                               ("onpolicy_alignment", "alignment (committed sub-plans achieved)", "^"),
                               ("rollout_subgoals", "goal atoms holding at the end", "D")):
        # a figure a round does not have (the twin writes no sub-plans) is a gap, not a zero
        ax.plot(xs, [100 * r[key] if r.get(key) is not None else float("nan") for r in rows], marker=marker,
                linestyle="none", label=label)
    # round names carry the variant ("1 (no instruction dropout)"): wrapped so neighbours do not overlap
    ax.set_xticks(xs, [textwrap.fill(str(r["round"]), 14) for r in rows], fontsize=8)
    ax.set_xlabel("checkpoint or setting (round log)")
    ax.set_ylabel("%")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.set_title(title, fontsize=10)
    fig.legend(*ax.get_legend_handles_labels(), loc="lower center", ncol=2, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.1, 1, 1))  # the legend below the axes: it hid the first round's points
    fig.savefig(path)
    return Path(path)
