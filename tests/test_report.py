"""`seal report`: statistics, table layout, plots, HTML escaping and the HTML in headless Chromium.

The store fixture is written with the real ResultStore and real trial files (trace, grid PNG,
MP4); the outcomes are chosen so every count in the tables is known in advance.
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from seal.errors import InvalidInput
from seal.eval.store import ResultStore, TrialRow
from seal.eval.trials import MethodSpec, trial_seed
from seal.report import write_report
from seal.report.data import ReportData
from seal.report.stats import (
    mcnemar_exact,
    paired_difference,
    paired_from_counts,
    wilson,
)
from seal.report.tables import paired_rows

BASE, SEAL, SEAL2 = MethodSpec(method="base"), MethodSpec(k=10), MethodSpec(k=2)
# Their names in the report (seal.report.labels).
BASE_N, SEAL_N, SEAL2_N = "scripted expert", "scripted expert + SEAL (oracle)", "scripted expert + SEAL (oracle, K=2)"
HOSTILE = "<script>document.body.setAttribute('data-pwned','1')</script><img src=x onerror=alert(1)> & \"q\""
N = 10  # trials per task

# Successes per (suite, task, method): trial t succeeds if t < count.
OUTCOMES = {("libero_10", 0): {BASE: 5, SEAL: 9, SEAL2: 7},
            ("libero_10", 1): {BASE: 10, SEAL: 10, SEAL2: 10},
            ("composition", 3): {BASE: 0, SEAL: 4}}


def _write_trial_files(root: Path, spec: MethodSpec, suite: str, task: int, trial: int) -> tuple[str, str]:
    """A trace with a hostile rationale, a candidate grid and a short real MP4, laid out as the runner does."""
    import imageio.v2 as imageio

    d = root / suite / str(task) / f"{spec.method}-{spec.config_hash}" / f"trial{trial:03d}"
    (d / "grids").mkdir(parents=True)
    events = [
        {"event": "subplan", "t": 0.1, "step": 0, "text": "pick up the <b>soup</b>", "reasoning": "Plans: 1. a. 2. b."},
        {"event": "candidate", "t": 1.0, "round": 0, "slot": 0, "steps": 40, "ended_by": "think", "error": None,
         "verdict": {"success": False, "rationale": HOSTILE, "latency_s": 0.1, "score": 0.0, "cached": False}},
        {"event": "candidate", "t": 1.1, "round": 0, "slot": 1, "steps": 45, "ended_by": "think", "error": None,
         "verdict": {"success": True, "rationale": "Grasped(soup) is true", "latency_s": 0.1, "score": 1.0,
                     "cached": True}},
        {"event": "commit", "t": 1.2, "slot": 1, "round": 0, "steps": 45, "ended_by": "think",
         "verdict": {"success": True, "rationale": "Grasped(soup) is true"}},
        {"event": "episode_end", "t": 1.3, "success": False, "steps": 45, "sim_error": False, "ended_by": "idle"},
    ]
    (d / "trace.jsonl").write_text("".join(json.dumps(e) + "\n" for e in events))
    grid = np.zeros((60, 120, 3), np.uint8)
    grid[:, :60] = (200, 30, 30)
    grid[:, 60:] = (30, 200, 30)
    Image.fromarray(grid).save(d / "grids" / "subplan01_round0.png")
    with imageio.get_writer(d / "episode.mp4", fps=5, macro_block_size=1) as video:
        for i in range(5):
            video.append_data(np.full((64, 64, 3), 40 * i, np.uint8))
    return str(d / "trace.jsonl"), str(d / "episode.mp4")


def _ending(suite: str, success: bool) -> str:
    """Stored ``ended_by``: "" (a row from before the column) for LIBERO-10 failures, whose one trace
    file then answers for trial 5 and nothing for the others."""
    if success:
        return "goal_holds"
    return "policy_finished" if suite == "composition" else ""


def _refusals(spec: MethodSpec, suite: str, task: int, t: int) -> int:
    """Claims of completion the verifier refused: SEAL (K=10) was sent back once in two libero_10
    episodes it then solved, and twice in two composition episodes that still ended on a claim."""
    if spec is not SEAL:
        return 0
    if (suite, task) == ("libero_10", 0) and t < 2:
        return 1
    return 2 if suite == "composition" and t in (4, 5) else 0


@pytest.fixture(scope="module")
def store_path(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("report")
    db = root / "results.db"
    runs = root / "results_runs"
    with ResultStore(db) as store:
        for spec in (BASE, SEAL, SEAL2):
            store.register_method(spec.config_hash, spec.label, spec.canonical())
        for (suite, task), per_method in OUTCOMES.items():
            for spec, count in per_method.items():
                for t in range(N):
                    trace, video = ("", "")
                    if suite == "libero_10" and task == 0 and t == 5:
                        trace, video = _write_trial_files(runs, spec, suite, task, t)
                    store.add(TrialRow(method=spec.label, config_hash=spec.config_hash, suite=suite, task=task,
                                       trial=t, init_index=t, seed=trial_seed(suite, task, t), success=t < count,
                                       steps=100, wall_s=20.0 * spec.effective_k, step_s=5.0,
                                       verifier_calls=3 * (spec.method == "seal"), input_tokens=1000, output_tokens=50,
                                       cost_usd=0.01, subplans=["pick up the soup", "place it in the basket"],
                                       subplans_audited=2, subplans_aligned=1 + (spec.method == "seal"),
                                       ended_by=_ending(suite, t < count),
                                       done_refusals=_refusals(spec, suite, task, t),
                                       trace_path=trace, video_path=video, worker="w1"))
        # A seal trial base never ran: must not enter any paired comparison.
        store.add(TrialRow(method=SEAL.label, config_hash=SEAL.config_hash, suite="libero_10", task=0, trial=N,
                           init_index=0, seed=1, success=True, steps=100, wall_s=200.0))
        # A crashed trial with success=1 stored by mistake: still a failure in every table.
        store.add(TrialRow(method=SEAL2.label, config_hash=SEAL2.config_hash, suite="composition", task=3, trial=0,
                           init_index=0, seed=1, status="error", success=True,
                           error="Traceback (most recent call last):\n  File \"x.py\"\nRuntimeError: <boom> & bust",
                           worker="w2"))
    return db


@pytest.fixture(scope="module")
def report(store_path, tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "report"
    return write_report(store_path, out)


# ---- statistics ---------------------------------------------------------------------------------
def test_wilson_matches_published_values():
    # Newcombe (1998), "Two-sided confidence intervals for the single proportion", score method.
    for (x, n), (lo, hi) in {(81, 263): (0.2553, 0.3662), (15, 148): (0.0624, 0.1605),
                             (0, 20): (0.0, 0.1611), (1, 29): (0.0061, 0.1718)}.items():
        got = wilson(x, n)
        assert got == pytest.approx((lo, hi), abs=5e-5), (x, n, got)
    assert wilson(10, 10) == pytest.approx((0.7225, 1.0), abs=5e-5)
    # the ends are exact: computed, 0 of 7 gave a lower bound 1e-17 above the estimate 0 (a negative
    # error bar, which matplotlib refuses)
    for n in (3, 6, 7, 12, 14):
        assert wilson(0, n)[0] == 0.0 and wilson(n, n)[1] == 1.0
    assert all(math.isnan(v) for v in wilson(0, 0))
    with pytest.raises(ValueError):
        wilson(3, 2)


def test_paired_interval_and_mcnemar_match_published_values():
    # Newcombe's square-and-add interval for paired proportions, 2x2 table [[59, 6], [16, 80]]
    # (the contingencytables R package's worked example): -0.0621 (-0.1186 to -0.0046).
    d = paired_from_counts(59, 6, 16, 80)
    assert d.diff == pytest.approx(-0.0621, abs=5e-5)
    assert d.ci == pytest.approx((-0.1186, -0.0046), abs=5e-5)
    assert mcnemar_exact(12, 2) == pytest.approx(2 * (1 + 14 + 91) / 2 ** 14)
    assert mcnemar_exact(0, 0) == 1.0 and mcnemar_exact(5, 5) == 1.0
    same = paired_difference([(True, True)] * 3 + [(False, False)] * 2)
    assert same.diff == 0 and same.ci[0] < 0 < same.ci[1] and same.p_value == 1.0


def test_paired_differences_on_the_store(store_path):
    data = ReportData(store_path)
    assert data.pairs(SEAL.config_hash, BASE.config_hash, "composition") == [(t < 4, False) for t in range(N)]
    rows = {(r.suite, r.a.label, r.b.label): r.result for r in paired_rows(data)}
    # libero_10: task 0 base 5/10 vs seal 9/10, task 1 both 10/10; seal's unpaired trial 10 left out.
    d = rows[("libero_10", SEAL_N, BASE_N)]
    assert (d.n, d.both, d.only_a, d.only_b, d.neither) == (20, 15, 4, 0, 1)
    assert d.diff == pytest.approx(0.2)
    assert d.p_value == pytest.approx(2 / 16)
    assert d.ci == pytest.approx(paired_from_counts(15, 4, 0, 1).ci)
    # Overall: composition adds 4 seal-only successes over 10 more pairs.
    d = rows[("all", SEAL_N, BASE_N)]
    assert (d.n, d.only_a, d.only_b) == (30, 8, 0) and d.diff == pytest.approx(8 / 30)
    assert d.ci[0] > 0  # eight discordant pairs all one way: a real difference
    # seal[k=2]'s only composition trial crashed (stored with success=1): it pairs as a failure.
    d = rows[("composition", SEAL2_N, BASE_N)]
    assert (d.n, d.neither) == (1, 1)


# ---- tables -------------------------------------------------------------------------------------
def _md_table(md: str, title: str) -> list[list[str]]:
    block = md.split(f"### {title}")[1].split("\n\n")[1]
    return [[c.strip() for c in line.strip().strip("|").split(" | ")] for line in block.splitlines()]


def test_markdown_layout(report):
    md = report.markdown.read_text()
    rows = _md_table(md, "libero_10: success rate (%)")
    header = rows[0]
    assert header[:5] == ["Task", "Instruction", BASE_N, SEAL2_N, SEAL_N]
    assert header[5:] == ["paper π0-reason", "paper SEAL"]
    assert [r[0] for r in rows[2:]] == ["0", "1", "Average", "Average, common starts"]
    task0, task1, avg, common = rows[2], rows[3], rows[4], rows[5]
    assert task0[1] == "put both the alphabet soup and the tomato sauce in the basket"
    assert task0[2] == "50.0 [23.7, 76.3]"  # Wilson 5/10
    assert task0[3] == "70.0 [39.7, 89.2]"
    assert task0[4] == "**90.9 [62.3, 98.4] (n=11)**"  # 10/11 (its extra trial succeeded): best, n marked
    assert all(c.startswith("**100.0") for c in task1[2:5])  # ties are all bold
    assert avg[4].startswith("**95.2") and not avg[2].startswith("**")  # pooled 20/21
    # SEAL's extra trial makes its Average pool another set of starts: the common-starts row leaves it out
    assert [c.split(" [")[0].strip("*") for c in common[2:5]] == ["75.0", "85.0", "95.0"]
    assert "common starts" in md.split("libero_10: success rate (%)")[1].split("composition")[0]
    # The paper's Table VII/II numbers, trained on LIBERO-100, task 0: pi0_reason 90, seal 100.
    assert task0[5:] == ["90.0", "100.0"]
    comp = _md_table(md, "composition: success rate (%)")
    assert comp[0][2:] == [BASE_N, SEAL2_N, SEAL_N, "paper π0-reason", "paper SEAL"]
    assert "1 err" in comp[2][3] and comp[2][3].startswith("0.0")  # crash with success=1 stored: failure
    assert "RuntimeError: <boom> & bust" in md  # error trials listed with their last traceback line


def test_csv_layout(report):
    by_name = {p.name: p for p in report.csv}
    rows = list(csv.DictReader(by_name["success_libero_10.csv"].read_text().splitlines()))
    assert [r["task"] for r in rows] == ["0", "1", "average", "common"]
    assert rows[3][f"{SEAL_N} n"] == "20"  # the starts every method ran
    assert float(rows[0][f"{BASE_N} success_pct"]) == 50.0 and rows[0][f"{BASE_N} n"] == "10"
    assert float(rows[0][f"{SEAL_N} ci_low"]) == pytest.approx(100 * wilson(10, 11)[0], abs=0.01)
    assert rows[0]["paper seal"] == "100.0" and rows[2][f"{SEAL_N} n"] == "21"
    long = list(csv.DictReader(by_name["success_long.csv"].read_text().splitlines()))
    comp = [r for r in long if r["suite"] == "composition" and r["method"] == SEAL2_N and r["task"] == "3"]
    assert comp[0]["errors"] == "1" and comp[0]["successes"] == "0"
    runtime = {r["method"]: r for r in csv.DictReader(by_name["runtime.csv"].read_text().splitlines())}
    assert float(runtime[BASE_N]["wall_s_per_executed_step"]) == pytest.approx(0.2)  # 20 s / 100 steps
    assert float(runtime[SEAL2_N]["verifier_calls_per_trial"]) == pytest.approx(60 / 21, abs=0.01)
    align = {(r["suite"], r["method"]): r for r in csv.DictReader(by_name["alignment.csv"].read_text().splitlines())}
    endings = {(r["method"], r["ended_by"]): (int(r["episodes"]), int(r["failed"]))
               for r in csv.DictReader(by_name["endings.csv"].read_text().splitlines())}
    # base: 15 successes; of the 5 failures of libero_10 task 0, trial 5's trace says idle and 4 say
    # nothing; composition's 10 failures were stored as policy_finished. The crashed SEAL2 row is "error".
    assert {k[1]: v for k, v in endings.items() if k[0] == BASE_N} == {
        "goal_holds": (15, 0), "idle": (1, 1), "not recorded": (4, 4), "policy_finished": (10, 10)}
    assert endings[(SEAL2_N, "error")] == (1, 1)
    claims = {r["method"]: tuple(int(r[k]) for k in ("trials", "episodes_with_false_claim", "claims_refused",
                                                        "ended_on_false_claim", "refused_then_solved"))
              for r in csv.DictReader(by_name["completions.csv"].read_text().splitlines())}
    # base never checks: its 10 composition failures ended on a claim. SEAL: 6 composition failures
    # ended on a claim (2 of them after refusals), 2 libero_10 episodes were sent back and solved.
    assert claims[BASE_N] == (30, 10, 0, 10, 0)
    assert claims[SEAL_N] == (31, 8, 6, 6, 2)
    assert claims[SEAL2_N] == (21, 0, 0, 0, 0)
    base, seal2 = align[("libero_10", BASE_N)], align[("libero_10", SEAL2_N)]
    assert float(base["alignment_rate"]) == 0.5 and float(seal2["alignment_rate"]) == 1.0
    assert base["subplans_audited"] == str(2 * N * 2)  # 2 per trial, 2 tasks; totals, not a mean of rates
    # per suite: composition's rows stand apart; SEAL2 has only its crashed trial there
    assert align[("composition", BASE_N)]["subplans_audited"] == str(2 * N)
    assert (align[("composition", SEAL2_N)]["trials"], align[("composition", SEAL2_N)]["subplans_audited"]) == ("1", "0")
    errors = list(csv.DictReader(by_name["errors.csv"].read_text().splitlines()))
    assert len(errors) == 1 and errors[0]["method"] == SEAL2_N


def test_plots_written(report):
    names = {p.name for p in report.plots}
    assert names == {"success_by_suite.png", "runtime_vs_k.png"}
    for p in report.plots:
        img = np.asarray(Image.open(p).convert("RGB"))
        assert img.shape[0] > 300 and img.shape[1] > 500
        assert len(np.unique(img.reshape(-1, 3), axis=0)) > 20  # drawn, not a blank canvas


def test_bad_input(store_path, tmp_path):
    with pytest.raises(InvalidInput, match="valid: copy, link, none"):
        write_report(store_path, tmp_path / "r", media="embed")
    with pytest.raises(InvalidInput, match="libero_100_basket"):
        write_report(store_path, tmp_path / "r", paper_training="libero_90")
    with pytest.raises(InvalidInput, match="no results database"):
        write_report(tmp_path / "missing.db", tmp_path / "r")
    with ResultStore(tmp_path / "empty.db"):
        pass
    with pytest.raises(InvalidInput, match="no finished trials"):
        write_report(tmp_path / "empty.db", tmp_path / "r")
    with pytest.raises(InvalidInput, match="libero_90.*it holds: composition, libero_10"):
        write_report(store_path, tmp_path / "r", suites=["libero_10", "libero_90"])


# ---- HTML ---------------------------------------------------------------------------------------
def _episode_page(report) -> Path:
    return next(p for p in report.episodes if p.name == f"libero_10-t0-{SEAL.config_hash}-005.html")


def test_html_escapes_hostile_text(report):
    page = _episode_page(report).read_text()
    assert "<script" not in page and "<img src=x" not in page
    assert "&lt;script&gt;document.body.setAttribute(&#x27;data-pwned&#x27;,&#x27;1&#x27;)&lt;/script&gt;" in page
    assert "&amp; &quot;q&quot;" in page
    assert "pick up the &lt;b&gt;soup&lt;/b&gt;" in page  # sub-plan text from the trace, escaped too
    assert "script-src &#x27;none&#x27;" in page  # CSP as a second line of defence
    index = report.index_html.read_text()
    assert "RuntimeError: &lt;boom&gt; &amp; bust" in index and "<boom>" not in index


def test_html_media_copied_and_linked(report):
    page = _episode_page(report)
    html = page.read_text()
    media = report.index_html.parent / "media" / page.stem
    assert (media / "episode.mp4").stat().st_size > 0 and (media / "grids" / "subplan01_round0.png").exists()
    assert f'src="../media/{page.stem}/episode.mp4"' in html
    assert f'src="../media/{page.stem}/grids/subplan01_round0.png"' in html
    assert "Grasped(soup) is true" in html and "(cached)" in html


def test_report_cli(store_path, tmp_path):
    from seal.cli import main

    out = tmp_path / "cli_report"
    assert main(["report", str(store_path), "--out", str(out), "--media", "link", "--no-episodes"]) == 0
    assert (out / "index.html").exists() and (out / "report.md").exists() and not (out / "episodes").exists()
    # one suite of two: the other leaves every table
    only = tmp_path / "one_suite"
    assert main(["report", str(store_path), "--out", str(only), "--media", "none", "--no-episodes",
                 "--suites", "composition"]) == 0
    md = (only / "report.md").read_text()
    assert "### composition: success rate" in md and "### libero_10" not in md and "| libero_10 |" not in md


def test_report_some_methods(store_path, tmp_path, capsys):
    from seal.cli import main
    from seal.report.data import ReportData

    everyone = ReportData(store_path).methods
    first, other = everyone[0], everyone[-1]
    out = tmp_path / "one_method"
    assert main(["report", str(store_path), "--out", str(out), "--media", "none", "--no-episodes",
                 "--methods", first.label.upper()]) == 0
    md = (out / "report.md").read_text()
    assert f"| {first.label} |" in md and f"| {other.label} |" not in md
    kept = ReportData(store_path, methods=[first.config_hash[:6], other.config_hash[:6]]).methods
    assert [m.config_hash for m in kept] == [first.config_hash, other.config_hash]
    part = other.spec_label[:4]  # a part of the stored method string keeps every configuration that has it
    assert {m.config_hash for m in ReportData(store_path, methods=[part]).methods} == \
        {m.config_hash for m in everyone if part in m.spec_label}
    assert main(["report", str(store_path), "--out", str(out), "--methods", "policy_ckpt=nothing"]) == 2
    err = capsys.readouterr().err
    assert "'policy_ckpt=nothing' names no method" in err and first.label in err


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _chromium(*args: str, tmp: Path) -> subprocess.CompletedProcess:
    cmd = [CHROMIUM, "--headless", "--disable-gpu", "--hide-scrollbars", "--no-first-run",
           f"--user-data-dir={tmp / 'chrome-profile'}", *args]
    if os.geteuid() == 0:  # Chromium refuses to run as root with its sandbox on
        cmd.insert(1, "--no-sandbox")
    return subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=90)


def test_html_report_in_headless_chromium(report, tmp_path):
    # Fails rather than skips: `make install` installs Chromium (and stops if it cannot), so a
    # missing browser is a broken install, and a skip here would hide the only real-browser check.
    assert CHROMIUM is not None, ("chromium is not installed (Debian package `chromium`): run `make install`, "
                                  "or `apt-get install chromium`")
    index = report.index_html
    shot = tmp_path / "index.png"
    res = _chromium(f"--screenshot={shot}", "--window-size=1280,1600", index.as_uri(), tmp=tmp_path)
    assert shot.exists(), res.stderr[-2000:]
    img = np.asarray(Image.open(shot).convert("RGB"))
    assert img.shape[:2] == (1600, 1280)
    assert img.std() > 20 and len(np.unique(img.reshape(-1, 3), axis=0)) > 200  # text, tables, plots drawn

    dom = _chromium("--dump-dom", index.as_uri(), tmp=tmp_path).stdout
    assert dom.count("<table") >= 5 and "libero_10: success rate (%)" in dom and "paper SEAL" in dom
    assert 'class="best"' in dom and "Paired differences" in dom

    # The hostile rationale stays text in a real browser: no script ran, no element was injected.
    page = _episode_page(report)
    dom = _chromium("--dump-dom", page.as_uri(), tmp=tmp_path).stdout
    assert "Grasped(soup) is true" in dom and "<video" in dom
    assert 'data-pwned="1"' not in dom and "<img src=\"x\"" not in dom
    assert "&lt;script&gt;document.body.setAttribute" in dom


# ---- verifier errors ----------------------------------------------------------------------------
def test_verifier_errors_are_a_column_a_warning_and_a_mark(report, tmp_path):
    """A verifier that failed past its retries must show: per-trial counts, a warning on top of the
    Markdown and the HTML, a marked episode page. The clean fixture report has no such warning."""
    assert "verification(s)" not in report.markdown.read_text() and 'class="warn"' not in report.index_html.read_text()

    db = tmp_path / "r.db"
    runs = tmp_path / "r_runs"
    trace, video = _write_trial_files(runs, SEAL, "libero_10", 0, 0)
    events = [json.loads(line) for line in Path(trace).read_text().splitlines()]
    events[1]["verdict"] = {"success": None, "rationale": "verifier unavailable after 4 attempt(s): HTTP 503",
                            "latency_s": 2.0, "score": None, "cached": False, "error": "APIStatusError HTTP 503"}
    Path(trace).write_text("".join(json.dumps(e) + "\n" for e in events))
    with ResultStore(db) as store:
        store.register_method(SEAL.config_hash, SEAL.label, SEAL.canonical())
        common = dict(method=SEAL.label, config_hash=SEAL.config_hash, suite="libero_10", task=0, steps=100,
                      wall_s=10.0)
        store.add(TrialRow(**common, trial=0, init_index=0, seed=0, verifier_calls=6, verifier_errors=5,
                           verifier_unavailable=True, fallbacks=2, trace_path=trace, video_path=video))
        store.add(TrialRow(**common, trial=1, init_index=1, seed=1, verifier_calls=6, verifier_errors=1,
                           fallbacks=0, success=True))
        store.add(TrialRow(**common, trial=2, init_index=2, seed=2, verifier_calls=4, success=True))
    paths = write_report(db, tmp_path / "out")

    md = paths.markdown.read_text()
    assert "Warning: 6 verification(s) in 2 trial(s) got no answer" in md
    assert "1 trial(s) had the verifier unavailable in most of their rounds" in md
    assert "verifier errors" in md and "trials mostly unverified" in md and "fallbacks / trial" in md
    runtime = list(csv.DictReader((tmp_path / "out" / "csv" / "runtime.csv").read_text().splitlines()))
    assert (runtime[0]["verifier_errors"], runtime[0]["trials_mostly_unverified"]) == ("6", "1")
    assert float(runtime[0]["fallbacks_per_trial"]) == pytest.approx(2 / 3, abs=1e-3)
    per_trial = list(csv.DictReader((tmp_path / "out" / "csv" / "verifier_errors.csv").read_text().splitlines()))
    assert [(r["trial"], r["verifier_errors"], r["verifier_unavailable"]) for r in per_trial] == \
        [("0", "5", "1"), ("1", "1", "0")]

    index = paths.index_html.read_text()
    assert 'class="warn" id="verifier-warning"' in index and "Verifier errors" in index
    pages = {p: p.read_text() for p in paths.episodes}
    marked = [p for p, text in pages.items() if "mostly unverified" in text]
    assert len(marked) == 1 and "5 of 6 verification(s) got no answer" in pages[marked[0]]
    assert "unknown: verifier error (APIStatusError HTTP 503)" in pages[marked[0]]
