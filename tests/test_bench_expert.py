"""`seal bench expert`: resumable per-episode log, init ranges, the JSON summary."""

from __future__ import annotations

import json

import pytest

from seal.benchmarks import expert as bench
from seal.cli import main
from seal.errors import InvalidInput


def _row(task, knobs, init, success, version="v1", grip="fingers"):
    return {"suite": "libero_10", "task": task, "knobs": knobs, "init": init, "success": success,
            "steps": 100 + init, "sim_error": False, "wall_s": 1.0, "version": version, "grip": grip}


def test_summary_reports_fractions_and_failing_inits():
    rows = [_row(0, "clean", 0, True), _row(0, "clean", 1, False), _row(1, "clean", 0, True),
            _row(1, "clean", 1, True), _row(0, "misaligned", 0, False), _row(0, "misaligned", 1, True)]
    out = bench.summarize(rows, "libero_10", trials=2, first_init=0)
    assert out["per_task_success"] == {"0": 0.5, "1": 1.0}
    assert out["mean_success"] == 0.75
    assert out["failed_inits"] == {"0": [1]}
    assert out["misaligned_per_task_success"] == {"0": 0.5}
    assert out["misaligned_failed_inits"] == {"0": [0]}
    assert out["mean_steps"] == 100.5
    assert not any(k.startswith("pads_") for k in out)


def test_summary_keeps_the_two_grip_checks_apart():
    """--grip fingers,pads: the default check's keys are bare, the pad check's prefixed, from the same inits."""
    rows = [_row(0, "clean", 0, True), _row(0, "clean", 1, True), _row(0, "clean", 0, False, grip="pads"),
            _row(0, "clean", 1, True, grip="pads"), _row(0, "misaligned", 0, False, grip="pads")]
    out = bench.summarize(rows, "libero_10", trials=2, first_init=0)
    assert out["per_task_success"] == {"0": 1.0} and out["pads_per_task_success"] == {"0": 0.5}
    assert out["pads_failed_inits"] == {"0": [0]} and out["failed_inits"] == {}
    assert out["pads_misaligned_mean_success"] == 0.0 and "misaligned_mean_success" not in out


def test_log_refuses_other_code_and_tolerates_a_torn_last_line(tmp_path):
    log = tmp_path / "log.jsonl"
    log.write_text(json.dumps(_row(0, "clean", 0, True)) + "\n" + '{"suite": "libero_10", "ta')
    assert list(bench.read_log(log, "v1")) == [("libero_10", 0, "clean", 0, 0.0, "fingers")]  # rows before --dart: 0
    old = {k: v for k, v in _row(0, "clean", 0, True).items() if k != "grip"}
    log.write_text(json.dumps(old) + "\n")  # a row from before --grip: the expert read the pad check
    assert list(bench.read_log(log, "v1")) == [("libero_10", 0, "clean", 0, 0.0, "pads")]
    with pytest.raises(InvalidInput, match="code version 'v1'.*another --log"):
        bench.read_log(log, "v2")
    log.write_text("not json\n" + json.dumps(_row(0, "clean", 0, True)) + "\n")
    with pytest.raises(InvalidInput, match="log.jsonl:1 is not an expert-benchmark row"):
        bench.read_log(log, "v1")


def test_resume_runs_only_missing_episodes(tmp_path, capsys):
    """One real episode runs; the one already logged (same code version) is taken from the log."""
    log = tmp_path / "log.jsonl"
    version = bench.code_version()
    log.write_text(json.dumps(_row(1, "clean", 5, False, version)) + "\n")
    assert main(["bench", "expert", "--tasks", "1", "--trials", "2", "--first-init", "4", "--no-misaligned",
                 "--workers", "1", "--log", str(log)]) == 0
    out = json.loads(capsys.readouterr().out)
    rows = [json.loads(line) for line in log.read_text().splitlines()]
    assert [r["init"] for r in rows] == [5, 4]  # init 5 was not re-run; init 4 appended
    assert out["episodes"] == 2 and out["first_init"] == 4
    assert out["failed_inits"].get("1", []) == sorted([5] + ([4] if not rows[1]["success"] else []))
    assert out["dart"] == 0.0 and rows[1]["dart"] == 0.0
    assert main(["bench", "expert", "--tasks", "1", "--trials", "1", "--first-init", "5", "--no-misaligned",
                 "--dart", "2"]) != 0
    assert "--dart must be a noise std in [0, 1]" in capsys.readouterr().err


def test_bad_ranges_are_named(capsys):
    assert main(["bench", "expert", "--tasks", "0", "--trials", "1", "--first-init", "50", "--no-misaligned"]) != 0
    assert "50 init states; --first-init 50 is past them" in capsys.readouterr().err
    assert main(["bench", "expert", "--tasks", "a,b", "--no-misaligned"]) != 0
    assert "comma-separated task ids" in capsys.readouterr().err
    assert main(["bench", "expert", "--tasks", "0", "--trials", "1", "--no-misaligned", "--grip", "pads,palms"]) != 0
    assert "--grip must list distinct checks among fingers, pads, got 'pads,palms'" in capsys.readouterr().err
