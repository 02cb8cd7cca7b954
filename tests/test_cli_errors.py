"""Bad input ends in one line, ``seal: error: <what was wrong and what is valid>``, exit status 2,
and leaves nothing behind: no traceback, no value silently replaced by a default, no empty output
folder, no database. Ctrl-C during `seal verify collect` prints one line saying what was kept.
(issue 30, "Bad input")"""

from __future__ import annotations

import glob
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from _verifier_cases import write_cases

from seal.cli import main
from seal.errors import InvalidInput


def _seal(argv: list, capsys) -> tuple[int, str]:
    """Exit status and stderr of ``seal ARGV`` run in this process."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own errors exit from inside parse_args
        code = exc.code
    return code, capsys.readouterr().err


def _assert_refused(code: int, err: str, *words: str) -> None:
    """Exit 2 and one closing ``seal: error:`` line naming ``words``; no traceback."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err
    assert "Traceback" not in err, err
    assert lines and lines[-1].startswith("seal: error: "), err
    assert sum(line.startswith("seal: error:") for line in lines) == 1, err
    for w in words:
        assert w in lines[-1], (w, err)


def _never(what: str):
    """A stand-in for the work a refused command must not start."""

    def fail(*args, **kwargs):
        raise AssertionError(f"{what} started although the command should have been refused")

    return fail


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    """A tiny `seal verify collect` layout (synthetic, no simulator)."""
    return write_cases(tmp_path_factory.mktemp("cases"), 12, tasks=("libero_10/0", "libero_10/1"), inits=4)


# ---- 1. `seal eval --db` where no database can be written ------------------------------------
def _unwritable_db(tmp_path: Path) -> tuple[Path, Path]:
    """(a --db path that cannot be created, the folder to check for leftovers)."""
    if os.geteuid() != 0:
        folder = tmp_path / "read-only"
        folder.mkdir()
        folder.chmod(0o555)
        return folder / "sub" / "results.db", folder
    # root writes through permission bits: use a file system that takes no new files
    if not Path("/proc/self").is_dir():
        pytest.skip("needs a read-only folder (running as root, and no /proc)")
    return Path("/proc") / f"seal-test-{os.getpid()}.db", Path("/proc")


def _contents(folder: Path) -> set[str] | None:
    """What is in ``folder`` (None for /proc, whose entries come and go with processes)."""
    return None if folder == Path("/proc") else set(os.listdir(folder))


def test_eval_db_in_a_read_only_folder_is_one_line_not_a_traceback(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("seal.eval.runner.make_backend", _never("a trial"))
    db, folder = _unwritable_db(tmp_path)
    before = _contents(folder)
    try:
        code, err = _seal(["eval", "--db", db, "--out", tmp_path / "runs", "--methods", "base", "--tasks", "0",
                           "--trials", "1"], capsys)
        _assert_refused(code, err, str(db), "results database", "write")
        assert _contents(folder) == before and not db.exists()
    finally:
        if folder != Path("/proc"):
            folder.chmod(0o755)
    assert not (tmp_path / "runs").exists()


def test_result_store_refuses_an_unwritable_place_and_removes_what_it_made(tmp_path):
    from seal.eval.store import ResultStore

    db, folder = _unwritable_db(tmp_path)
    before = _contents(folder)
    try:
        with pytest.raises(InvalidInput, match="cannot create the results database"):
            ResultStore(db)
        assert _contents(folder) == before and not db.exists()
    finally:
        if folder != Path("/proc"):
            folder.chmod(0o755)


# ---- 2. `seal train verifier`: every setting checked before any work ---------------------------
@pytest.mark.parametrize("option,value,words", [
    ("--jitter", "-2", "jitter must be in [0, 1)"),
    ("--jitter", "1.5", "jitter must be in [0, 1)"),
    ("--holdout-inits", "1", "holdout_inits must be in [0, 1)"),
    ("--holdout-inits", "nan", "holdout_inits must be in [0, 1)"),
    ("--image-size", "0", "image_size must be an integer in 8..224"),
    ("--weight-decay", "-1", "weight_decay must be a finite number >= 0"),
    ("--ema", "1", "ema decay must be in [0, 1)"),
    ("--seed", "-1", "seed must be an integer >= 0"),
    ("--train-seed", "-3", "train_seed must be an integer >= 0"),
    ("--lr", "-1", "argument --lr: must be a number > 0"),
    ("--lr", "nan", "argument --lr: must be a number > 0"),
    ("--threads", "0", "argument --threads: must be an integer >= 1"),
    ("--save-every-min", "0", "argument --save-every-min: must be a number > 0"),
])
def test_train_verifier_refuses_each_bad_setting_before_any_work(option, value, words, cases, tmp_path, capsys):
    out = tmp_path / "run"
    code, err = _seal(["train", "verifier", "--data", cases, "--out", out, "--image-size", "32", "--steps", "2",
                       option, value], capsys)
    _assert_refused(code, err, words)
    assert not out.exists()


@pytest.mark.parametrize("field,value,words", [
    ("steps", -5, "steps must be an integer >= 0"),
    ("batch_size", 0, "batch_size must be an integer >= 1"),
    ("lr", 0.0, "lr must be a finite number > 0"),
    ("lr", float("inf"), "lr must be a finite number > 0"),
    ("weight_decay", float("nan"), "weight_decay must be a finite number >= 0"),
    ("image_size", 500, "image_size must be an integer in 8..224"),
    ("image_size", 32.0, "image_size must be an integer"),
    ("holdout_tasks", "libero_10/1", "holdout_tasks must be a tuple of task keys"),
    ("holdout_inits", -0.1, "holdout_inits must be in [0, 1)"),
    ("seed", -1, "seed must be an integer >= 0"),
    ("train_seed", -1, "train_seed must be an integer >= 0"),
    ("shift", 96, "shift must be an integer in 0..95"),
    ("jitter", -2.0, "jitter must be in [0, 1)"),
    ("lr_schedule", "linear", "constant, cosine"),
    ("ema", 1.0, "ema decay must be in [0, 1)"),
    ("log_every", 0, "log_every must be an integer >= 1"),
    ("eval_every", 0, "eval_every must be an integer >= 1"),
    ("save_every_s", -1.0, "save_every_s must be a number of seconds >= 0"),
])
def test_verifier_train_config_checks_every_field(field, value, words):
    pytest.importorskip("torch")
    from seal.train.verifier import VerifierTrainConfig

    with pytest.raises(InvalidInput) as caught:
        VerifierTrainConfig(**{field: value})
    assert words in str(caught.value) and repr(value) in str(caught.value)
    VerifierTrainConfig(steps=0, jitter=0.5, holdout_inits=0.0, ema=0.999, train_seed=3)  # all fine


# ---- 3. a value given is refused, never silently replaced by a default --------------------------
@pytest.mark.parametrize("argv,words", [
    (["verify", "collect", "--k", "0"], "argument --k: must be an integer >= 1, got 0"),
    (["verify", "collect", "--rounds", "0"], "argument --rounds: must be an integer >= 1, got 0"),
    (["verify", "collect", "--workers", "0"], "argument --workers: must be an integer >= 1, got 0"),
    (["verify", "collect", "--patience", "-1"], "argument --patience: must be an integer >= 1, got -1"),
    (["verify", "collect", "--max-episodes", "0"], "argument --max-episodes: must be an integer >= 1"),
    (["verify", "collect", "--max-steps", "0"], "argument --max-steps: must be an integer >= 1"),
    (["verify", "collect", "--k", "2", "--workers", "3"], "--workers must be in 1..2"),
])
def test_verify_collect_refuses_counts_it_used_to_replace(argv, words, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("seal.collect.collect", _never("the collection"))
    out = tmp_path / "cases"
    code, err = _seal([*argv, "--out", out], capsys)
    _assert_refused(code, err, words)
    assert not out.exists()


@pytest.mark.parametrize("what,option,value", [
    ("verifier", "--steps", "-5"), ("verifier", "--steps", "0"), ("verifier", "--batch", "0"),
    ("verifier", "--batch-size", "-1"), ("verifier", "--lr", "0"), ("value", "--steps", "0"),
    ("value", "--batch-size", "0"), ("value", "--lr", "0"), ("value", "--holdout", "1"), ("vla", "--steps", "0"),
    ("vla", "--eval-every", "0"), ("vla", "--save-minutes", "-1"),
])
def test_train_refuses_counts_it_used_to_replace(what, option, value, cases, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("seal.train.verifier.train_verifier", _never("training"))
    monkeypatch.setattr("seal.train.pipeline.train_value_on_dataset", _never("training"))
    out = tmp_path / "run"
    code, err = _seal(["train", what, "--data", cases, "--dataset", cases, "--annotations", cases, "--out", out,
                       option, value], capsys)
    _assert_refused(code, err, f"argument {option}", "must be")
    assert not out.exists()


def test_collect_options_refuse_what_they_used_to_replace():
    from seal.collect import CollectOptions

    for bad, words in (({"k": 0}, "--k must be an integer >= 1"), ({"per_task": 0}, "--per-task"),
                       ({"workers": 0}, "--workers must be an integer >= 1"), ({"patience": 0}, "--patience"),
                       ({"k": 2, "workers": 3}, "--workers must be in 1..2"), ({"init_source": "x"}, "init source")):
        with pytest.raises(InvalidInput, match=words.replace(".", r"\.")):
            CollectOptions(suite="libero_10", tasks=[0], **bad)


# ---- 4. `seal bench verifier-sweep --points` is read before the sweep runs ----------------------
def test_sweep_reads_its_points_before_any_episode(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("seal.sim.pool.EnvPool", _never("the sweep"))
    out = tmp_path / "sweep"
    base = ["bench", "verifier-sweep", "--tasks", "0", "--trials", "1", "--fp", "0", "--fn", "0", "--k", "2",
            "--out", out]
    missing = tmp_path / "missing.json"
    code, err = _seal([*base, "--points", missing], capsys)
    _assert_refused(code, err, "--points", str(missing))
    assert not out.exists()
    for name, content, words in (("list.json", [1, 2], "no fp_rate / fn_rate"),
                                 ("text.json", {"fp_rate": "x", "fn_rate": 0.1}, "fp_rate 'x'"),
                                 ("rate.json", {"fp_rate": 0.1, "fn_rate": 1.5}, "fn_rate 1.5")):
        path = tmp_path / name
        path.write_text(json.dumps(content))
        code, err = _seal([*base, "--points", path], capsys)
        _assert_refused(code, err, str(path), words)
        assert not out.exists()
    code, err = _seal([*base, "--workers", "3"], capsys)  # more simulators than candidates
    _assert_refused(code, err, "--workers must be in 1..2")
    assert not out.exists()


# ---- 5. Ctrl-C during `seal verify collect` ------------------------------------------------------
def test_pool_workers_ignore_ctrl_c_the_parent_handles_it():
    from seal.sim.pool import EnvPool

    with EnvPool(("libero_10", 0), k=1, workers=1) as pool:
        pid = pool.worker_pids()[0]
        os.kill(pid, signal.SIGINT)  # what a terminal's Ctrl-C sends to every process of the group
        time.sleep(0.5)
        pool.reset(0)  # still serving, not restarted
        assert pool.worker_pids() == [pid] and pool.crashes == 0


def test_ctrl_c_during_collect_prints_what_was_kept_and_no_worker_traceback(tmp_path):
    out = tmp_path / "cases"
    seal = Path(sys.executable).with_name("seal")
    cmd = [str(seal)] if seal.is_file() else [sys.executable, "-m", "seal.cli"]
    # A target it cannot reach before the interrupt, so only Ctrl-C can end it. SIG_DFL in the child:
    # a test run started as a background job (or a pytest-xdist worker) passes SIGINT on ignored,
    # and Python then never turns it into KeyboardInterrupt (the run went on to its end).
    proc = subprocess.Popen([*cmd, "verify", "collect", "--tasks", "0", "--per-task", "2000", "--k", "2", "--workers",
                             "2", "--init-source", "official", "--max-steps", "60", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 240
        while not glob.glob(str(out / "data" / "*.parquet")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.2)
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.5)  # into the next episode: workers busy stepping
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C: the whole process group, workers included
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    lines = [line for line in err.splitlines() if line.strip()]
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert len(lines) == 1 and lines[0].startswith("seal: interrupted: "), err
    assert str(out) in lines[0] and "run the same command again to continue" in lines[0], err
    for _ in range(50):  # the workers went with their parent
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.2)
    else:
        os.killpg(proc.pid, signal.SIGKILL)
        pytest.fail("pool workers outlived the interrupted collection")


# ---- 6. refused commands leave no output folder and no database --------------------------------
def test_refused_training_leaves_no_run_folder(tmp_path, capsys):
    pytest.importorskip("torch")
    for argv, words in ((["train", "verifier", "--data", tmp_path / "none"], "holds no verification cases"),
                        (["train", "vla", "--annotations", tmp_path / "none"], "not an annotation directory")):
        out = tmp_path / "run"
        code, err = _seal([*argv, "--out", out], capsys)
        _assert_refused(code, err, words)
        assert not out.exists(), list(out.iterdir())


@pytest.mark.parametrize("argv,words", [
    (["--trials", "0"], "argument --trials: must be an integer >= 1, got 0"),
    (["--workers", "0"], "argument --workers: must be an integer >= 1"),
    (["--pool-workers", "0"], "argument --pool-workers: must be an integer >= 1"),
    (["--max-steps", "-1"], "argument --max-steps: must be an integer >= 1"),
    (["--backend", "slurm"], "unknown backend 'slurm'"),
])
def test_refused_eval_leaves_no_database(argv, words, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("seal.eval.runner.make_backend", _never("a trial"))
    db = tmp_path / "new" / "results.db"
    code, err = _seal(["eval", "--db", db, "--methods", "base", "--tasks", "0", *argv], capsys)
    _assert_refused(code, err, words)
    assert not (tmp_path / "new").exists()


def test_run_eval_checks_its_arguments_before_opening_the_store(tmp_path):
    from seal.eval.execute import RunOptions
    from seal.eval.runner import run_eval
    from seal.steer.method import MethodSpec

    db = tmp_path / "results.db"
    for kwargs, words in (({"trials": 0}, "--trials must be >= 1"), ({"backend": "x"}, "unknown backend"),
                          ({"workers": 0}, "--workers must be"), ({"pool_workers": 0}, "--pool-workers must be"),
                          ({"max_steps": 0}, "--max-steps must be")):
        options = RunOptions(out_dir=str(tmp_path / "runs"), pool_workers=kwargs.pop("pool_workers", 1),
                             max_steps=kwargs.pop("max_steps", None))
        with pytest.raises(InvalidInput, match=words):
            run_eval(str(db), [MethodSpec(method="base")], ["libero_10"], [0], kwargs.pop("trials", 1),
                     options=options, **kwargs)
        assert not db.exists()


# ---- the rest of the command line: nonsense counts and rates are refused up front ---------------
@pytest.mark.parametrize("argv,words", [
    (["run", "--max-steps", "0"], "argument --max-steps: must be an integer >= 1, got 0"),
    (["run", "--init", "-1"], "argument --init: must be an integer >= 0, got -1"),
    (["run", "--k", "0"], "argument --k: must be an integer >= 1"),
    (["run", "--port", "70000"], "argument --port: must be an integer in 1..65535, got 70000"),
    (["run", "--request-timeout", "nan"], "argument --request-timeout: must be a number > 0"),
    (["run", "--false-positive", "1.5"], "argument --false-positive: must be a number in [0, 1]"),
    (["demos", "record", "--out", "{out}", "--workers", "0"], "argument --workers: must be an integer >= 1"),
    (["demos", "record", "--out", "{out}", "--dart", "-0.1"], "argument --dart: must be a number >= 0"),
    (["demos", "record", "--out", "{out}", "--image-size", "0"], "argument --image-size: must be an integer >= 1"),
    (["verify", "from-demos", "--dataset", "{out}", "--out", "{out}", "--episodes-per-task", "0"],
     "argument --episodes-per-task: must be an integer >= 1"),
    (["suites", "generate", "libero_10", "--n", "0"], "argument --n: must be an integer >= 1"),
    (["suites", "check", "libero_10", "--inits", "0"], "argument --inits: must be an integer >= 1"),
    (["annotate", "{out}", "--backend", "offline", "--out", "{out}", "--concurrency", "0"],
     "argument --concurrency: must be an integer >= 1"),
    (["annotate", "{out}", "--backend", "offline", "--out", "{out}", "--max-retries", "-1"],
     "argument --max-retries: must be an integer >= 0"),
    (["bench", "steer", "--k", "0"], "argument --k: must be an integer >= 1"),
    (["bench", "steer", "--trials", "0"], "argument --trials: must be an integer >= 1"),
    (["bench", "expert", "--first-init", "-1"], "argument --first-init: must be an integer >= 0"),
    (["bench", "runtime", "--latency", "-2"], "argument --latency: must be a number >= 0"),
    (["bench", "verifier", "--threshold", "2"], "argument --threshold: must be a number in [0, 1]"),
    (["bench", "verifier", "--limit", "0"], "argument --limit: must be an integer >= 1"),
    (["train", "value", "--out", "{out}", "--gamma", "1.5"], "argument --gamma: must be a number in [0, 1]"),
    (["train", "value", "--out", "{out}", "--expectile", "1"], "argument --expectile: must be a number in (0, 1)"),
])
def test_nonsense_counts_and_rates_are_refused_in_one_line(argv, words, tmp_path, capsys, monkeypatch):
    import seal.cli

    patched = 0
    for command in seal.cli.COMMANDS:  # no command may start: the value is refused while parsing
        for name in dir(command):
            if name.startswith("_cmd_"):
                monkeypatch.setattr(command, name, _never(f"{command.__name__}.{name}"))
                patched += 1
    assert patched >= len(seal.cli.COMMANDS)
    out = tmp_path / "out"
    code, err = _seal([a.replace("{out}", str(out)) for a in argv], capsys)
    _assert_refused(code, err, words)
    assert len([line for line in err.splitlines() if line.strip()]) == 1, err  # no usage dump for a bad value
    assert not out.exists()
