"""The static HTML report: ``index.html`` (tables, plots, an episode index) and one page per
episode (video, sub-plans, candidate grids, every verdict with its rationale).

Every string that came from the database or a trace goes through ``html.escape``: verifier
rationales are free text written by a VLM and must never become markup. The pages carry no script
at all, and a Content-Security-Policy forbids any, as a second line of defence.

Media (videos, grids) are copied into the report directory by default so the folder can be zipped
or served as is; ``media="link"`` points at the run directory with relative links instead.
"""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

from seal.eval.store import TrialRow
from seal.report.data import ReportData, succeeded
from seal.report.tables import Table, last_line

MEDIA_MODES = ("copy", "link", "none")

_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:24px;color:#1b1f24;max-width:1400px}
h1{font-size:1.6em}h2{border-bottom:1px solid #d0d7de;padding-bottom:4px;margin-top:1.6em}
table{border-collapse:collapse;margin:8px 0 4px;font-size:13px}
th,td{border:1px solid #d0d7de;padding:3px 7px;text-align:right;vertical-align:top}
th{background:#f3f5f7}td.text,th.text{text-align:left}
td.best{font-weight:700;background:#e6f4ea}
.note{color:#57606a;font-size:12px;margin:2px 0}
.ok{color:#1a7f37;font-weight:600}.fail{color:#cf222e;font-weight:600}.err{color:#9a6700;font-weight:600}
pre{background:#f6f8fa;padding:8px;overflow-x:auto;white-space:pre-wrap;font-size:12px}
img.plot{max-width:100%;border:1px solid #d0d7de;margin:6px 0}
img.grid{max-width:100%;border:1px solid #d0d7de;margin:4px 0}
video{max-width:448px;border:1px solid #d0d7de}
details{margin:6px 0}summary{cursor:pointer}
.ep a{text-decoration:none}
.warn{background:#fff8c5;border:1px solid #d4a72c;padding:6px 10px;font-weight:600}
"""

# No script may run in these pages; inline styles are ours.
_CSP = "default-src 'self' file: data:; script-src 'none'; object-src 'none'; style-src 'unsafe-inline'"


def esc(value) -> str:
    return html.escape("" if value is None else str(value), quote=True)


def _page(title: str, body: str) -> str:
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta http-equiv="Content-Security-Policy" content="{esc(_CSP)}">'
            f"<title>{esc(title)}</title><style>{_CSS}</style></head>\n<body>\n{body}\n</body></html>\n")


def table_html(t: Table, *, table_id: str = "") -> str:
    ident = f' id="{esc(table_id)}"' if table_id else ""
    head = "".join(f'<th class="text">{esc(h)}</th>' if j < t.left else f"<th>{esc(h)}</th>"
                   for j, h in enumerate(t.headers))
    rows = []
    for i, row in enumerate(t.rows):
        cells = []
        for j, c in enumerate(row):
            cls = [c_ for c_, on in (("text", j < t.left), ("best", (i, j) in t.bold)) if on]
            attr = f' class="{" ".join(cls)}"' if cls else ""
            cells.append(f"<td{attr}>{esc(c)}</td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    notes = "".join(f'<p class="note">{esc(n)}</p>' for n in t.notes)
    if not t.rows:
        return f"<h3>{esc(t.title)}</h3>\n{notes}\n"
    return (f"<h3>{esc(t.title)}</h3>\n<table{ident}><thead><tr>{head}</tr></thead>"
            f"<tbody>{''.join(rows)}</tbody></table>\n{notes}\n")


def _safe(name: str) -> str:
    """A file-name-safe version of a label or suite name."""
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", name)


def episode_id(row: TrialRow) -> str:
    return f"{_safe(row.suite)}-t{row.task}-{_safe(row.config_hash)}-{row.trial:03d}"


@dataclass
class MediaPlacer:
    """Puts a trial file where the report can reach it and returns its URL relative to a page."""

    out_dir: Path
    mode: str

    def place(self, src: Path | None, episode: str, name: str, page_dir: Path) -> str | None:
        if src is None or self.mode == "none":
            return None
        if self.mode == "copy":
            dest = self.out_dir / "media" / episode / name
            dest.parent.mkdir(parents=True, exist_ok=True)
            if not dest.exists() or dest.stat().st_mtime < src.stat().st_mtime:
                shutil.copy2(src, dest)
            target = dest
        else:
            target = src.resolve()
        return quote(os.path.relpath(target, page_dir.resolve()).replace(os.sep, "/"))


# ---- index ------------------------------------------------------------------------------------
def write_index(data: ReportData, out_dir: Path, *, sections: list[tuple[str, list[Table]]],
                plots: list[Path], episode_pages: dict[str, Path], markdown: Path, csvs: list[Path]) -> Path:
    out_dir = Path(out_dir)
    n_err = len(data.errors())
    parts = ["<h1>SEAL evaluation report</h1>",
             (f'<p class="note">Database <code>{esc(data.db_path)}</code> · {len(data.rows)} trials · '
             f"{len(data.methods)} method configurations · suites {esc(', '.join(data.suites))} · "
             f"{n_err} error trial(s) · generated {esc(time.strftime('%Y-%m-%d %H:%M:%S'))}</p>"),
             _file_links(out_dir, markdown, csvs), _methods_html(data)]
    if data.verifier_warning():
        parts.insert(2, f'<p class="warn" id="verifier-warning">{esc(data.verifier_warning())}</p>')
    if plots:
        parts.append('<h2 id="plots">Plots</h2>')
        parts += [f'<img class="plot" alt="{esc(p.stem)}" src="{quote(p.relative_to(out_dir).as_posix())}">'
                  for p in plots]
    for title, tables in sections:
        parts.append(f"<h2>{esc(title)}</h2>")
        parts += [table_html(t, table_id=f"t-{_safe(t.title)[:40]}") for t in tables]
    if data.errors():
        parts.append("<h3>Tracebacks</h3>")
        for r in data.errors():
            link = episode_pages.get(episode_id(r))
            name = f"{data.label_of(r)} {r.suite}/{r.task} #{r.trial}"
            title = f'<a href="{quote(link.relative_to(out_dir).as_posix())}">{esc(name)}</a>' if link else esc(name)
            parts.append(f"<details><summary>{title}: {esc(last_line(r.error))}</summary><pre>{esc(r.error)}</pre></details>")
    parts.append('<h2 id="episodes">Episodes</h2>')
    parts.append('<p class="note">✓ success, ✗ failure, ! error. Each links to the episode page (video, '
                 "sub-plans, candidate grids, verifier rationales).</p>")
    parts += [_episode_index(data, suite, episode_pages, out_dir) for suite in data.suites]
    path = out_dir / "index.html"
    path.write_text(_page("SEAL evaluation report", "\n".join(parts)))
    return path


def _file_links(out_dir: Path, markdown: Path, csvs: list[Path]) -> str:
    links = [markdown, *csvs]
    items = " · ".join(f'<a href="{quote(p.relative_to(out_dir).as_posix())}">{esc(p.name)}</a>' for p in links)
    return f'<p class="note">Files: {items}</p>'


def _methods_html(data: ReportData) -> str:
    rows = "".join(f'<tr><td class="text">{esc(m.label)}</td><td class="text"><code>{esc(m.spec_label)}</code></td>'
                   f'<td class="text"><code>{esc(m.config_hash)}</code></td>'
                   f'<td class="text"><code>{esc(json.dumps(m.config, sort_keys=True))}</code></td></tr>'
                   for m in data.methods)
    return ('<details><summary>Method configurations</summary><table><thead><tr><th class="text">method</th>'
            '<th class="text">seal eval label</th><th class="text">config hash</th><th class="text">settings</th>'
            f"</tr></thead><tbody>{rows}</tbody></table></details>")


def _episode_index(data: ReportData, suite: str, pages: dict[str, Path], out_dir: Path) -> str:
    methods = data.methods_in(suite)
    by_key = {(r.config_hash, r.task, r.trial): r for r in data.rows if r.suite == suite}
    trials = sorted({(r.task, r.trial) for r in data.rows if r.suite == suite})
    head = "".join(f"<th>{esc(m.label)}</th>" for m in methods)
    body = []
    for task, trial in trials:
        cells = []
        for m in methods:
            r = by_key.get((m.config_hash, task, trial))
            if r is None:
                cells.append("<td></td>")
                continue
            mark, cls = ("!", "err") if r.status == "error" else ("✓", "ok") if succeeded(r) else ("✗", "fail")
            page = pages.get(episode_id(r))
            inner = f'<span class="{cls}">{mark}</span>'
            if page is not None:
                inner = f'<a href="{quote(page.relative_to(out_dir).as_posix())}">{inner} {r.steps} steps</a>'
            cells.append(f'<td class="ep">{inner}</td>')
        body.append(f"<tr><td>{task}</td><td>{trial}</td>{''.join(cells)}</tr>")
    fold = " open" if len(trials) <= 200 else ""  # long indexes start folded
    return (f"<details{fold}><summary>{esc(suite)} ({len(trials)} task-trials)</summary>"
            f'<table><thead><tr><th>task</th><th>trial</th>{head}</tr></thead><tbody>{"".join(body)}</tbody>'
            "</table></details>")


# ---- one episode -------------------------------------------------------------------------------
def write_episode(data: ReportData, row: TrialRow, out_dir: Path, media: MediaPlacer) -> Path:
    from seal.steer.trace import read_trace

    ident = episode_id(row)
    page_dir = Path(out_dir) / "episodes"
    page_dir.mkdir(parents=True, exist_ok=True)
    label = data.label_of(row)
    result = ("error", "err") if row.status == "error" else ("success", "ok") if succeeded(row) else ("failure", "fail")
    parts = ['<p><a href="../index.html#episodes">← report</a></p>',
             f"<h1>{esc(label)} · {esc(row.suite)} task {row.task} · trial {row.trial}</h1>",
             f"<p><b>Instruction:</b> {esc(data.instruction(row.suite, row.task))}</p>",
             (f'<p>Result: <span class="{result[1]}">{result[0]}</span> · {row.steps} executed steps · '
             f"{row.wall_s:.1f} s wall · {row.verifier_calls} verifier calls · {row.input_tokens}+"
             f"{row.output_tokens} tokens · ${row.cost_usd:.4f} · init state {row.init_index} · seed {row.seed}"
             f"{' · simulator error' if row.sim_error else ''} · worker {esc(row.worker)}</p>")]
    if row.verifier_errors or row.verifier_unavailable:
        parts.append(f'<p class="warn">{row.verifier_errors} of {row.verifier_calls} verification(s) got no '
                     f"answer from the verifier (errors past the retries)"
                     f"{'; in most rounds the verifier never answered, so this result is mostly unverified' if row.verifier_unavailable else ''}"
                     ".</p>")
    if row.status == "error":
        parts.append(f"<h2>Traceback</h2><pre>{esc(row.error)}</pre>")
    video_src = data.resolve(row.video_path)
    url = media.place(video_src, ident, "episode.mp4", page_dir)
    parts.append("<h2>Episode video</h2>")
    if url:
        parts.append(f'<video controls preload="metadata" src="{url}"></video>')
    elif row.video_path and video_src is None:
        parts.append(f'<p class="note">Video {esc(row.video_path)} not found (moved? pass --runs DIR).</p>')
    else:
        parts.append('<p class="note">No video for this trial (by default `seal eval` records failures only).</p>')
    if row.subplans:
        parts.append("<h2>Sub-plans</h2><ol>" + "".join(f"<li>{esc(s)}</li>" for s in row.subplans) + "</ol>")
    if row.goal_status:
        parts.append("<h2>Goal at the end</h2><ul>" + "".join(
            f'<li><code>{esc(k)}</code>: <span class="{"ok" if v else "fail"}">{esc(v)}</span></li>'
            for k, v in row.goal_status.items()) + "</ul>")
    trace_path = data.resolve(row.trace_path)
    parts.append("<h2>Steering trace</h2>")
    if trace_path is None:
        parts.append(f'<p class="note">Trace {esc(row.trace_path) or "(none)"} not found.</p>')
    else:
        grids_dir = trace_path.parent / "grids"
        parts.append(_trace_html(read_trace(trace_path, strict=False), grids_dir, ident, media, page_dir))
    path = page_dir / f"{ident}.html"
    path.write_text(_page(f"{label} {row.suite}/{row.task} #{row.trial}", "\n".join(parts)))
    return path


def _trace_html(events: list[dict], grids_dir: Path, ident: str, media: MediaPlacer, page_dir: Path) -> str:
    """Sub-plan by sub-plan: the reasoning, the candidate grids, each candidate's verdict, the commit.
    Grid files are numbered by sub-plan (1-based) and round, as the steering engine writes them."""
    out, index, candidates = [], 0, []

    def flush() -> None:
        if candidates:
            out.append(_candidates_table(candidates))
            candidates.clear()

    for ev in events:
        kind = ev.get("event")
        if kind == "subplan":
            flush()
            index += 1
            out.append(f"<h3>Sub-plan {index}: {esc(ev.get('text'))} <span class=\"note\">(at step "
                       f"{esc(ev.get('step'))}, t={esc(ev.get('t'))} s)</span></h3>")
            if ev.get("reasoning"):
                out.append(f"<pre>{esc(ev.get('reasoning'))}</pre>")
            for grid in sorted(grids_dir.glob(f"subplan{index:02d}_round*.png")) if grids_dir.is_dir() else []:
                url = media.place(grid, ident, f"grids/{grid.name}", page_dir)
                if url:
                    out.append(f'<p class="note">{esc(grid.stem)}</p><img class="grid" alt="{esc(grid.stem)}" src="{url}">')
        elif kind == "candidate":
            candidates.append(ev)
        elif kind == "commit":
            flush()
            v = ev.get("verdict") or {}
            why = f" — verdict: {esc(v.get('rationale'))}" if v else ""
            out.append(f"<p><b>Committed</b> candidate #{esc(ev.get('slot'))} of round {esc(ev.get('round'))} "
                       f"({esc(ev.get('ended_by'))}), now at step {esc(ev.get('steps'))}{why}</p>")
        elif kind == "episode_end":
            flush()
            ok = bool(ev.get("success"))
            out.append(f'<p><b>Episode end:</b> <span class="{"ok" if ok else "fail"}">'
                       f'{"success" if ok else "failure"}</span> after {esc(ev.get("steps"))} steps'
                       f'{" (simulator error)" if ev.get("sim_error") else ""}, t={esc(ev.get("t"))} s'
                       f'{", verifier errors: " + esc(ev.get("verifier_errors")) if ev.get("verifier_errors") else ""}'
                       f'{"; ended by " + esc(ev.get("ended_by")) if ev.get("ended_by") else ""}'
                       "</p>")
            if ev.get("reasoning"):  # the policy's text that declared the task complete
                out.append(f"<pre>{esc(ev.get('reasoning'))}</pre>")
    flush()
    return "\n".join(out) if out else '<p class="note">The trace is empty.</p>'


def _candidates_table(cands: list[dict]) -> str:
    rows = []
    for c in cands:
        v = c.get("verdict")
        if v is None:
            verdict, cls = "–", ""
        else:
            ok = v.get("success")
            verdict, cls = ("pass", "ok") if ok is True else ("fail", "fail") if ok is False else ("unknown", "err")
            if v.get("error"):
                verdict = f"unknown: verifier error ({v['error']})"
        rows.append(
            f"<tr><td>{esc(c.get('round'))}</td><td>{esc(c.get('slot'))}</td><td>{esc(c.get('steps'))}</td>"
            f'<td class="text">{esc(c.get("ended_by"))}{" — " + esc(c.get("error")) if c.get("error") else ""}</td>'
            f'<td class="text"><span class="{cls}">{esc(verdict)}</span></td>'
            f"<td>{esc(v.get('score') if v else '')}</td>"
            f"<td>{esc(v.get('latency_s') if v else '')}{' (cached)' if v and v.get('cached') else ''}</td>"
            f'<td class="text rationale">{esc(v.get("rationale") if v else "")}</td></tr>')
    return ('<table class="candidates"><thead><tr><th>round</th><th>slot</th><th>steps</th>'
            '<th class="text">ended by</th><th class="text">verdict</th><th>score</th><th>latency s</th>'
            f'<th class="text">rationale</th></tr></thead><tbody>{"".join(rows)}</tbody></table>')
