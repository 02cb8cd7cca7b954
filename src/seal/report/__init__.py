"""Reports from a results database: Markdown and CSV tables in the paper's layout, paired method
comparisons, runtime, PNG plots and a static HTML report with one page per episode.

``write_report(db, out_dir)`` does it all; ``seal report RESULTS.db`` is the command. What each
file holds and which statistics are used (and why) is in docs/reports.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from seal.errors import InvalidInput
from seal.report.data import ReportData
from seal.report.paper import DEFAULT_TRAINING, PaperResults


@dataclass
class ReportPaths:
    """Every file a report wrote."""

    index_html: Path
    markdown: Path
    csv: list[Path]
    plots: list[Path]
    episodes: list[Path] = field(default_factory=list)

    def all(self) -> list[Path]:
        return [self.index_html, self.markdown, *self.csv, *self.plots, *self.episodes]


def write_report(db: str | Path, out_dir: str | Path, *, runs_dir: str | Path | None = None, media: str = "copy",
                 paper_training: str = DEFAULT_TRAINING, episodes: bool = True, progress=None,
                 suites: list[str] | None = None, methods: list[str] | None = None) -> ReportPaths:
    """Read ``db`` and write the report into ``out_dir`` (created; files there are overwritten).

    ``runs_dir``: where the trial files are if they moved since the run (default: the stored paths,
    then ``<db without suffix>_runs``). ``media``: ``copy`` videos and grids into the report,
    ``link`` to them relatively, or ``none``. ``paper_training``: the paper's training set whose
    numbers go beside ours. ``progress(done, total)`` is called as episode pages are written.
    ``suites``: only these suites' trials (default: every suite in the store). ``methods``: only the
    method configurations these items name (`ReportData`; default all).
    """
    from seal.report import causes, html, lift, paper_layout, plots, tables

    if media not in html.MEDIA_MODES:
        raise InvalidInput(f"unknown media mode {media!r}; valid: {', '.join(html.MEDIA_MODES)}")
    paper = PaperResults.load()
    paper.check_training(paper_training)
    data = ReportData(db, runs_dir=runs_dir, suites=suites, methods=methods)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InvalidInput(f"report output {out} exists and is not a directory")
    (out / "csv").mkdir(parents=True, exist_ok=True)
    (out / "plots").mkdir(parents=True, exist_ok=True)

    success = [tables.success_table(data, s, paper, paper_training) for s in data.suites]
    paired = tables.paired_rows(data)
    runtime = tables.runtime_rows(data)
    alignment = tables.alignment_rows(data)
    endings = tables.ending_rows(data)
    completions = tables.completion_rows(data)
    failures = causes.cause_rows(data)
    passes = causes.pass_rows(data)
    candidates = causes.candidate_rows(data)
    layouts = paper_layout.layout_sections(data, paper, paper_training)
    lifts = lift.lift_rows([lay for _, group in layouts for lay in group])
    shares = lift.share_rows(data)
    same_starts = lift.same_start_rows(data)

    csvs = []
    for st in success:
        csvs.append(_write(out / "csv" / f"success_{st.suite}.csv", tables.success_csv(st)))
    csvs.append(_write(out / "csv" / "success_long.csv", tables.long_csv(data, success)))
    csvs.append(_write(out / "csv" / "paired_differences.csv", tables.paired_csv(paired)))
    csvs.append(_write(out / "csv" / "seal_minus_base.csv",
                       paper_layout.differences_csv([lay for _, group in layouts for lay in group])))
    csvs.append(_write(out / "csv" / "lift_by_suite.csv", lift.lift_csv(lifts)))
    csvs.append(_write(out / "csv" / "share_of_oracle_lift.csv", lift.share_csv(shares)))
    csvs.append(_write(out / "csv" / "same_starts.csv", lift.same_start_csv(same_starts)))
    csvs.append(_write(out / "csv" / "runtime.csv", tables.runtime_csv(runtime)))
    csvs.append(_write(out / "csv" / "alignment.csv", tables.alignment_csv(alignment)))
    csvs.append(_write(out / "csv" / "endings.csv", tables.ending_csv(endings)))
    csvs.append(_write(out / "csv" / "completions.csv", tables.completion_csv(completions)))
    csvs.append(_write(out / "csv" / "failure_causes.csv", causes.cause_csv(failures)))
    csvs.append(_write(out / "csv" / "committed_passes.csv", causes.pass_csv(passes)))
    csvs.append(_write(out / "csv" / "committed_passes_by_kind.csv", causes.pass_kind_csv(passes)))
    csvs.append(_write(out / "csv" / "candidates_by_kind.csv", causes.candidate_csv(candidates)))
    csvs.append(_write(out / "csv" / "errors.csv", tables.error_csv(data)))
    csvs.append(_write(out / "csv" / "verifier_errors.csv", tables.verifier_csv(data)))

    plot_paths = [plots.success_plot(data, success, out / "plots" / "success_by_suite.png"),
                  plots.runtime_vs_k_plot(data, runtime, out / "plots" / "runtime_vs_k.png")]

    sections = [("Success", [tables.success_display(st) for st in success]),
                *[(title, [paper_layout.layout_display(lay) for lay in group]) for title, group in layouts],
                ("Paired differences", [tables.paired_display(paired)]),
                ("Lift", [lift.lift_display(lifts), lift.same_start_display(same_starts), lift.share_display(shares)]),
                ("Alignment", [tables.alignment_display(alignment)]),
                ("Endings", [tables.ending_display(endings), tables.completion_display(completions)]),
                ("Failures", [causes.cause_display(failures), causes.pass_display(passes),
                              causes.pass_kind_display(passes), causes.candidate_display(candidates)]),
                ("Runtime", [tables.runtime_display(runtime)]),
                ("Errors", [tables.error_display(data), tables.verifier_display(data)])]
    md = _write(out / "report.md", _markdown(data, sections, plot_paths, out))

    pages: dict[str, Path] = {}
    if episodes:
        placer = html.MediaPlacer(out, media)
        for i, row in enumerate(data.rows):
            pages[html.episode_id(row)] = html.write_episode(data, row, out, placer)
            if progress is not None:
                progress(i + 1, len(data.rows))
    index = html.write_index(data, out, sections=sections, plots=plot_paths, episode_pages=pages,
                             markdown=md, csvs=csvs)
    return ReportPaths(index, md, csvs, plot_paths, list(pages.values()))


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _markdown(data: ReportData, sections, plot_paths: list[Path], out: Path) -> str:
    from seal.report.tables import to_markdown

    lines = ["# SEAL evaluation report", "",
             (f"Database `{data.db_path}`: {len(data.rows)} trials, {len(data.methods)} method configurations, "
             f"suites {', '.join(data.suites)}, {len(data.errors())} error trial(s)."), ""]
    if data.verifier_warning():
        lines += [f"> **{data.verifier_warning()}**", ""]
    for title, tabs in sections:
        lines += [f"## {title}", ""] + [to_markdown(t) for t in tabs]
    lines += ["## Plots", ""] + [f"![{p.stem}]({p.relative_to(out).as_posix()})" for p in plot_paths] + [""]
    return "\n".join(lines)
