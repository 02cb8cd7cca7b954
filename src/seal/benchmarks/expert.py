"""`seal bench expert`: success of the scripted expert, clean and in its misaligned setting.

Trials run over the official init states ``first_init .. first_init+trials-1`` of each task,
one episode per job, spread over worker processes (each keeps the world of the task it ran
last, so a task's episodes on one worker share one world build; no rendering).

A full LIBERO-10 run is 1,000 episodes, so with ``--log FILE`` every finished episode is
appended to a JSONL file as it lands; running the same command again skips the episodes
already there. Rows carry the code version (git tree hash of ``src/``, ``-dirty`` for uncommitted
changes): a log written by other code is refused rather than silently mixed into the figures.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import subprocess
import time
from pathlib import Path

import numpy as np

from seal.benchmarks.common import trials_of
from seal.errors import InvalidInput
from seal.sim.goals import GRASP_CHECKS
from seal.sim.suites import get_task, parse_task_ids

_SETTINGS = ("clean", "misaligned")
_cache: dict = {}  # per worker process: the last task's world (built once per task, not per episode)


def _episode(job: tuple) -> dict:
    suite, task_id, knobs, init, dart, grip = job
    from seal.episode import run_policy_episode
    from seal.policies.expert.policy import FailureKnobs, ScriptedExpert
    from seal.sim.world import LiberoWorld

    if _cache.get("key") != (suite, task_id):
        if "world" in _cache:
            _cache.pop("world").close()
        _cache["world"], _cache["key"] = LiberoWorld((suite, task_id)), (suite, task_id)
    world = _cache["world"]
    policy = ScriptedExpert.for_world(world, FailureKnobs.named(knobs), grip=grip)
    r = run_policy_episode(world, policy, init_index=init, dart=dart)
    return {"suite": suite, "task": task_id, "knobs": knobs, "init": init, "dart": dart, "grip": grip,
            "success": bool(r.success),
            "steps": r.steps, "sim_error": bool(r.sim_error), "wall_s": round(r.wall_s, 2)}


def code_version() -> str:
    """The git tree hash of ``src/`` (commits that touch only docs or tests keep it), with
    ``-dirty`` when ``src/`` has uncommitted changes."""
    root = Path(__file__).resolve().parents[3]
    try:
        commit = "src@" + subprocess.run(["git", "-C", str(root), "rev-parse", "--short=12", "HEAD:src"],
                                         capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no", "src"],
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return commit + ("-dirty" if dirty else "")


def read_log(path: Path, version: str) -> dict[tuple, dict]:
    """Episodes already in ``path``, keyed by (suite, task, knobs, init, dart, grip). Refuses foreign code versions."""
    done: dict[tuple, dict] = {}
    if not path.exists():
        return done
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
            key = (row["suite"], int(row["task"]), row["knobs"], int(row["init"]), float(row.get("dart", 0.0)),
                   row.get("grip", "pads"))
        except (ValueError, KeyError, TypeError):
            if n == len(path.read_text().splitlines()):
                continue  # a line cut short by a crash mid-write: that episode simply runs again
            raise InvalidInput(f"{path}:{n} is not an expert-benchmark row (expected JSON with suite, task, "
                               f"knobs, init); use another --log file") from None
        if row.get("version") != version:
            raise InvalidInput(f"{path} holds episodes from code version {row.get('version')!r}, this is "
                               f"{version!r}; results of different code must not be mixed: use another --log file")
        done[key] = row
    return done


def summarize(rows: list[dict], suite: str, trials: int, first_init: int) -> dict:
    """The benchmark's JSON: per-task success (fractions) per setting, steps, failing inits. Keys of the
    default grip check carry no prefix; the pad check's are prefixed ``pads_`` (``pads_mean_success``)."""
    out: dict = {"suite": suite, "trials": trials, "first_init": first_init, "episodes": len(rows)}
    for grip, knobs in [(g, k) for g in GRASP_CHECKS for k in _SETTINGS]:
        mine = [r for r in rows if r["knobs"] == knobs and r.get("grip", "pads") == grip]
        if not mine:
            continue
        tasks = sorted({r["task"] for r in mine})
        per_task = {t: [r for r in mine if r["task"] == t] for t in tasks}
        success = {str(t): round(float(np.mean([r["success"] for r in rs])), 3) for t, rs in per_task.items()}
        failed = {str(t): sorted(r["init"] for r in rs if not r["success"]) for t, rs in per_task.items()}
        prefix = ("" if grip == GRASP_CHECKS[0] else f"{grip}_") + ("" if knobs == "clean" else "misaligned_")
        out[f"{prefix}per_task_success"] = success
        out[f"{prefix}mean_success"] = round(float(np.mean(list(success.values()))), 3)
        out[f"{prefix}failed_inits"] = {t: v for t, v in failed.items() if v}
        if knobs == "clean":
            out[f"{prefix}mean_steps"] = round(float(np.mean([r["steps"] for r in mine])), 1)
    out["sim_errors"] = sum(r["sim_error"] for r in rows)
    return out


def _grips(text: str) -> list[str]:
    """``--grip fingers,pads``: the expert's in-hand checks to run, each on the same inits (the first is
    the one the progress bar shows)."""
    grips = [g.strip() for g in text.split(",") if g.strip()]
    bad = [g for g in grips if g not in GRASP_CHECKS]
    if bad or not grips or len(set(grips)) != len(grips):
        raise InvalidInput(f"--grip must list distinct checks among {', '.join(GRASP_CHECKS)}, got {text!r}")
    return grips


def run(args) -> dict:
    suite = args.suite
    tasks = parse_task_ids(suite, args.tasks)
    first = int(getattr(args, "first_init", 0) or 0)
    trials = trials_of(args, "expert")
    if first < 0:
        raise InvalidInput(f"--first-init must be >= 0, got {first}")
    settings = ["clean"] + ([] if args.no_misaligned else ["misaligned"])
    grips = _grips(getattr(args, "grip", None) or GRASP_CHECKS[0])
    from seal.episode import check_dart

    dart = check_dart(getattr(args, "dart", 0.0) or 0.0)
    jobs = []
    for t in tasks:
        n_inits = len(get_task(suite, t).init_states())
        last = min(first + trials, n_inits)
        if last <= first:
            raise InvalidInput(f"task {t} of {suite} has {n_inits} init states; --first-init {first} is past them")
        jobs += [(suite, t, k, i, dart, g) for k in settings for g in grips for i in range(first, last)]
    jobs.sort(key=lambda j: (j[1], j[2], j[3], j[5]))  # a task's episodes next to each other: one world per worker

    version = code_version()
    log = Path(args.log) if getattr(args, "log", None) else None
    done = read_log(log, version) if log else {}
    todo = [j for j in jobs if j not in done]
    rows = [done[j] for j in jobs if j in done]
    workers = max(1, min(args.workers or os.cpu_count() or 1, len(todo) or 1))

    from seal.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    start = time.perf_counter()
    # (seal's Progress writes to stderr: stdout stays one JSON object)
    with Progress(TextColumn("expert {task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("success {task.fields[rate]}"), TimeRemainingColumn()) as progress:
        bar = progress.add_task(suite, total=len(jobs), completed=len(rows), rate="-")
        with mp.get_context("spawn").Pool(workers) as pool, (log.open("a") if log else open(os.devnull, "w")) as fh:
            for row in pool.imap_unordered(_episode, todo, chunksize=1):
                row["version"] = version
                fh.write(json.dumps(row) + "\n")
                fh.flush()
                rows.append(row)
                clean = [r["success"] for r in rows if r["knobs"] == "clean" and r["grip"] == grips[0]]
                progress.update(bar, advance=1, rate=f"{np.mean(clean):.2f}" if clean else "-")
    out = summarize(rows, suite, trials, first)
    out["dart"] = dart
    out["wall_s"] = round(time.perf_counter() - start, 1)
    out["version"] = version
    return out
