"""scripts/traces.py: a results database's traces kept in append-only archives beside a snapshot of it, and
found again by `seal report` after the run directory is gone (no simulator: a tiny store and fake traces)."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

from seal.eval.store import ResultStore, TrialRow
from seal.report.data import ReportData

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "traces.py"
spec = importlib.util.spec_from_file_location("traces_script", SCRIPT)
traces = importlib.util.module_from_spec(spec)
spec.loader.exec_module(traces)

CONFIG = {"method": "base", "mode": "sync", "policy": "vla", "render": "fast"}


def _trial(store: ResultStore, runs: Path, trial: int) -> Path:
    trace = runs / "libero_10" / "0" / "base-abc123" / f"trial{trial:03d}" / "trace.jsonl"
    trace.parent.mkdir(parents=True)
    trace.write_text(json.dumps({"event": "episode_end", "ended_by": "done", "trial": trial}) + "\n")
    store.add(TrialRow(method="base", config_hash="abc123", suite="libero_10", task=0, trial=trial, init_index=trial,
                       seed=trial, trace_path=str(trace)))
    return trace


def test_pack_adds_only_new_traces_and_unpack_lets_the_report_find_them(tmp_path):
    live_db, live_runs = tmp_path / "runs" / "eval.db", tmp_path / "runs" / "eval_runs"
    with ResultStore(live_db) as store:
        store.register_method("abc123", "base", CONFIG)
        first = [_trial(store, live_runs, t) for t in (0, 1)]

    # a snapshot in the repository, packed from the live run directory
    snap = tmp_path / "repo" / "results" / "eval.db"
    snap.parent.mkdir(parents=True)
    shutil.copy(live_db, snap)
    one = traces.pack(snap, live_runs, traces.archive_dir(snap))
    assert one["added"] == 2 and one["not_on_disk"] == 0
    assert traces.pack(snap, live_runs, traces.archive_dir(snap))["added"] == 0  # nothing twice

    with ResultStore(live_db) as store:
        _trial(store, live_runs, 2)
    shutil.copy(live_db, snap)
    two = traces.pack(snap, live_runs, traces.archive_dir(snap))
    assert two["added"] == 1 and two["archive"] != one["archive"]
    with tarfile.open(one["archive"]) as tar:  # the first archive was not rewritten
        assert sorted(tar.getnames()) == ["libero_10/0/base-abc123/trial000/trace.jsonl",
                                  "libero_10/0/base-abc123/trial001/trace.jsonl"]

    # the machine is lost: only the repository's snapshot and archives remain
    shutil.rmtree(tmp_path / "runs")
    assert ReportData(snap).resolve(str(first[0])) is None
    out = subprocess.run([sys.executable, str(SCRIPT), "unpack", str(snap)], capture_output=True, text=True,
                         check=True)
    assert json.loads(out.stdout.splitlines()[-1])["traces"] == 3
    found = ReportData(snap).resolve(str(first[1]))
    assert found is not None and json.loads(found.read_text())["trial"] == 1


def test_a_missing_trace_is_counted_not_archived(tmp_path):
    db, runs = tmp_path / "eval.db", tmp_path / "eval_runs"
    with ResultStore(db) as store:
        store.register_method("abc123", "base", CONFIG)
        _trial(store, runs, 0).unlink()
        _trial(store, runs, 1)
    result = traces.pack(db, runs, traces.archive_dir(db))
    assert result["added"] == 1 and result["not_on_disk"] == 1
