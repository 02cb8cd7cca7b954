"""How many trials `scripts/generalization.sh` runs and roughly how many CPU hours they take.

Prints one JSON object: per suite and method the trials the script would run (and how many of
them a results database already holds), the seconds one trial is expected to take, where that
figure comes from, and the CPU hours. Reads the same environment as the script (SUITES, TASKS,
TRIALS, COMP_TRIALS, METHODS, MAX_STEPS, VALUE_CKPT); flags override it.

    .venv/bin/python scripts/generalization_plan.py [--costs RESULTS.db]
    scripts/generalization.sh --plan           # the same, with the script's DB as --costs if it exists

Per-trial cost, first match wins:
  1. rows of the same method configuration (config hash) in the same suite of the --costs database,
  2. the same configuration in other suites of it, scaled by how much dearer this suite's trials were than
     those suites' for other configurations of the same method and verifier (when the database has any),
  3. a stored configuration with the same method, policy weights, K and verifier (e.g. V-GPS with
     another value checkpoint),
  4. the documented defaults below.
Only finished trials (status 'ok') are used. One trial worker runs one trial at a time and its
simulator process mostly waits for it, so an hour of a trial's wall time is counted as one CPU hour.
The database is opened read-only; it is never changed.
"""

from __future__ import annotations

import argparse
import json
import os
import sqlite3
import sys
from pathlib import Path

from seal.errors import InvalidInput
from seal.sim.suites import MAX_STEPS, parse_task_ids

# ---- the run the script does: keep in step with scripts/generalization.sh -----------------------
SUITES = ("libero_10", "lang_rephrase", "lang_object_property", "visual_scene", "visual_viewpoint", "composition")
# short name -> (display name, `seal eval --methods` item); in the tables' order
METHODS = {
    "twin": ("twin (pi0)", "base:policy=vla:policy_ckpt=twin"),
    "twin_vgps": ("twin + V-GPS", "value:policy=vla:policy_ckpt=twin{value_ckpt}:k=10"),
    "vla": ("reasoning VLA", "base:policy=vla"),
    "vla_seal": ("reasoning VLA + SEAL (oracle)", "seal:policy=vla:k=10"),
    "vla_seal_learned": ("reasoning VLA + SEAL (learned verifier)", "seal:policy=vla:k=10:verifier=learned{threshold}"),
}
COMMON = {"render": "fast"}  # the script's shared method flag (--render fast)

# ---- documented defaults (used when no database has rows for a method) --------------------------
# Each method's cost is s_per_step x executed steps (capped by MAX_STEPS) + a per-trial overhead.
# docs/results.md, "LIBERO-10, learned VLAs (issue 14)": the twin and twin + V-GPS cost ~40 ms per
# executed step (V-GPS scores its K samples and simulates none). Their episodes mostly fail, so they
# are assumed to use the whole step budget (520 on every suite of these tables).
TWIN_S_PER_STEP = 0.040
# Same section: the reasoning VLA alone, 31 s per trial at 69 ms per executed step (~450 steps).
VLA_S_PER_STEP = 0.069
VLA_STEPS_PER_TRIAL = 31 / 0.069
# Same section: the reasoning VLA + SEAL (oracle, K=10), 232 s per trial at 849 ms per executed step
# (~273 steps) with other jobs on the 2 cores; docs/performance.md has 204 ms per step on a quiet machine.
SEAL_S_PER_STEP = 0.849
SEAL_STEPS_PER_TRIAL = 232 / 0.849
# docs/results.md, "SEAL with the learned verifier ... On the reasoning VLA": its verdicts add next to
# nothing (0.07 s of verifier wait per trial; docs/performance.md: 4-9 ms per verdict at K=10), so
# the oracle's figures stand in for it.
# docs/performance.md, `seal bench eval`: harness overhead per trial (world building, resets, traces,
# store), 3.1 s for an unsteered trial and 10.5 s for a SEAL trial.
BASE_OVERHEAD_S = 3.1
SEAL_OVERHEAD_S = 10.5

# ---- the LIBERO-100 training-set column (seed Table I): what it would cost here -----------------
# docs/performance.md, "On-policy data: DAgger collection and fine-tuning cost": 64-px demonstrations
# recorded at ~42 s each (one worker, a shared machine), and `seal train vla` at 19.2 samples/s (fp32,
# batch 32, one thread). The shipped VLA's manifest: 442 episodes, 89,478 frames, 6000 steps of batch 32.
DEMO_S = 42.0
DEMOS_PER_TASK = 50
LIBERO_100_TASKS = 100  # LIBERO-10 + LIBERO-90
LIBERO_10_DEMOS_ON_HAND = 143  # ../runs/data/l10_64 at the last count (docs/dagger.md)
FRAMES_PER_DEMO = 89_478 / 442
EPOCHS = 6000 * 32 / 89_478  # the shipped recipe's passes over its data
TRAIN_SAMPLES_PER_S = 19.2
CACHE_BYTES_PER_FRAME = 2 * 64 * 64 * 3  # two 64-px cameras, uint8 memmaps
# what the column runs: the LIBERO-100-trained VLA alone and steered, on every suite of the tables
COLUMN_METHODS = ("vla", "vla_seal", "vla_seal_learned")

DEFAULTS = {  # short name -> (s per executed step, executed steps per trial or None = the step limit, overhead s)
    "twin": (TWIN_S_PER_STEP, None, BASE_OVERHEAD_S),
    "twin_vgps": (TWIN_S_PER_STEP, None, BASE_OVERHEAD_S),
    "vla": (VLA_S_PER_STEP, VLA_STEPS_PER_TRIAL, BASE_OVERHEAD_S),
    "vla_seal": (SEAL_S_PER_STEP, SEAL_STEPS_PER_TRIAL, SEAL_OVERHEAD_S),
    "vla_seal_learned": (SEAL_S_PER_STEP, SEAL_STEPS_PER_TRIAL, SEAL_OVERHEAD_S),
}
# what decides "the same kind of method" for a cost taken from another configuration (rule 3)
_KIND_KEYS = ("method", "policy", "policy_ckpt", "k", "verifier", "model")


def method_item(name: str, value_ckpt: str | None) -> str:
    """The `--methods` item of a short name (the V-GPS one with VALUE_CKPT when the script was given
    one, else the package's shipped Q-function; the learned verifier's with LEARNED_THRESHOLD's
    operating point when the script was given one)."""
    threshold = os.environ.get("LEARNED_THRESHOLD", "")
    return METHODS[name][1].format(value_ckpt=f":value_ckpt={value_ckpt}" if value_ckpt else "",
                                   threshold=f":threshold={threshold}" if threshold else "")


def vgps_skip_reason(value_ckpt: str | None) -> str | None:
    """Why the twin + V-GPS method cannot run (its Q-function does not load), or None when it can.
    The script itself stops on such a method before its first trial, with the same message."""
    from seal.steer.method import parse_methods

    try:
        parse_methods(method_item("twin_vgps", value_ckpt), **COMMON)
    except InvalidInput as exc:
        return f"{exc} (the script stops before its first trial until VALUE_CKPT is fixed or unset)"
    return None


def _kind(canonical: dict) -> dict:
    return {k: canonical[k] for k in _KIND_KEYS if k in canonical}


def _method_identity(name: str, value_ckpt: str | None) -> tuple[str | None, dict]:
    """(config hash or None, the method's kind) without running anything. The V-GPS method without a
    usable checkpoint has no hash; its kind is the twin's with method=value and K=10."""
    from seal.steer.method import parse_methods

    if name == "twin_vgps" and vgps_skip_reason(value_ckpt) is not None:
        twin = parse_methods(method_item("twin", None), **COMMON)[0].canonical()
        return None, _kind(twin) | {"method": "value", "k": 10}
    spec = parse_methods(method_item(name, value_ckpt), **COMMON)[0]
    return spec.config_hash, _kind(spec.canonical())


class CostBook:
    """Finished trials of a results database, read once: (config hash, suite) -> [(wall s, steps)]."""

    def __init__(self, path: str | None):
        self.path = path
        self.rows: dict[tuple[str, str], list[tuple[float, int]]] = {}
        self.capped: dict[tuple[str, str], list[tuple[float, int]]] = {}  # trials cut short by --max-steps
        self.keys: set[tuple[str, str, int, int]] = set()  # (config hash, suite, task, trial) of every stored trial
        self.kinds: dict[str, dict] = {}
        if not path:
            return
        if not Path(path).is_file():
            raise SystemExit(f"generalization_plan: no results database at {path}")
        db = sqlite3.connect(f"file:{Path(path).resolve()}?mode=ro", uri=True)
        try:
            for h, config in db.execute("SELECT config_hash, config_json FROM methods"):
                self.kinds[h] = _kind(json.loads(config))
            has_ended_by = any(c[1] == "ended_by" for c in db.execute("PRAGMA table_info(trials)"))
            ended = "ended_by" if has_ended_by else "''"
            for h, suite, task, trial, status, wall, steps, ended_by in db.execute(
                    f"SELECT config_hash, suite, task, trial, status, wall_s, steps, {ended} FROM trials"):
                self.keys.add((h, suite, task, trial))
                if status != "ok":
                    continue
                # An episode that hit a step limit below its suite's own was run with --max-steps
                # (a smoke test): its wall time says nothing about a full trial.
                short = ended_by == "step_limit" and steps < MAX_STEPS.get(suite, 0)
                (self.capped if short else self.rows).setdefault((h, suite), []).append((wall, steps))
        except sqlite3.DatabaseError as exc:
            raise SystemExit(f"generalization_plan: {path} is not a `seal eval` results database ({exc})") from None
        finally:
            db.close()

    def cost(self, config_hash: str | None, kind: dict, suite: str, capped: bool = False) -> tuple[list, str]:
        """(rows to take the cost from, where they come from); no rows: use the defaults. Trials cut
        short by --max-steps count only when the plan is for capped trials too."""
        if capped:
            merged: dict = {}
            for book in (self.rows, self.capped):
                for key, rs in book.items():
                    merged.setdefault(key, []).extend(rs)
            return _pick(merged, self.kinds, config_hash, kind, suite)
        return _pick(self.rows, self.kinds, config_hash, kind, suite)


def _pick(rows: dict, kinds: dict, config_hash: str | None, kind: dict, suite: str) -> tuple[list, str]:
    """The first of: this configuration in this suite, in any suite, a configuration of the same kind."""
    if config_hash and (config_hash, suite) in rows:
        return rows[config_hash, suite], f"db: this configuration, {suite}"
    same = [r for (h, _), rs in rows.items() if h == config_hash for r in rs]
    if same:
        sources = sorted({s for (h, s) in rows if h == config_hash})
        factor, n = _suite_factor(rows, kinds, config_hash, kind, suite, sources)
        if factor is None:
            return same, "db: this configuration, other suites"
        return ([(w * factor, steps) for w, steps in same],
                f"db: this configuration, other suites, x{factor:.2f} for {suite} "
                f"(the ratio over {n} other configuration(s) of the method)")
    alike = [r for (h, _), rs in rows.items() if kinds.get(h) == kind for r in rs]
    if alike:
        return alike, "db: same method, policy, K and verifier, another configuration"
    return [], "default"


def _suite_factor(rows: dict, kinds: dict, config_hash: str, kind: dict, suite: str,
                  sources: list[str]) -> tuple[float | None, int]:
    """How much dearer a trial of ``suite`` is than one of ``sources``, measured on other configurations of
    the same method and verifier that ran both: (pooled ratio of mean wall times, configurations used),
    or (None, 0) when none did. Out of distribution SEAL's rounds fail more often and re-sample: on
    Lang-Object-Property round 2's SEAL trials took 3.8x their LIBERO-10 time, which a cost carried over
    from LIBERO-10 alone would miss."""
    def mean(h: str, suites: list[str]) -> float | None:
        ws = [w for s in suites for w, _ in rows.get((h, s), [])]
        return sum(ws) / len(ws) if ws else None

    same_kind = {k: kind.get(k) for k in ("method", "verifier")}
    there = here = 0.0
    n = 0
    for h in {h for (h, _) in rows if h != config_hash}:
        if {k: kinds.get(h, {}).get(k) for k in same_kind} != same_kind:
            continue
        a, b = mean(h, [suite]), mean(h, sources)
        if a is not None and b is not None:
            there, here, n = there + a, here + b, n + 1
    return (there / here, n) if n and here > 0 else (None, 0)


def seconds_per_trial(name: str, rows: list, step_limit: int, max_steps: int | None) -> float:
    cap = min(step_limit, max_steps) if max_steps else step_limit
    if rows:
        wall = sum(w for w, _ in rows)
        steps = sum(s for _, s in rows)
        if max_steps is None or steps == 0:
            return wall / len(rows)
        # a cap: the measured cost per executed step (overhead included) times the steps still allowed
        return wall / steps * min(cap, steps / len(rows))
    per_step, typical, overhead = DEFAULTS[name]
    return per_step * min(cap, typical if typical is not None else step_limit) + overhead


def _env_int(name: str, default: int) -> int:
    text = os.environ.get(name, "")
    return int(text) if text else default


def _split(text: str) -> list[str]:
    return [s.strip() for s in text.split(",") if s.strip()]


def plan(*, suites: list[str], methods: list[str], tasks: str, trials: int, comp_trials: int,
         max_steps: int | None, value_ckpt: str | None, costs: str | None) -> dict:
    for s in suites:
        if s not in SUITES:
            raise SystemExit(f"generalization_plan: unknown suite {s!r}; the tables' suites: {', '.join(SUITES)}")
    for m in methods:
        if m not in METHODS:
            raise SystemExit(f"generalization_plan: unknown method {m!r}; valid: {', '.join(METHODS)}")
    book = CostBook(costs)
    skip = {m: why for m in methods if m == "twin_vgps" and (why := vgps_skip_reason(value_ckpt))}
    ident = {m: _method_identity(m, value_ckpt) for m in methods}
    out_suites: dict = {}
    totals = {"trials": 0, "to_run": 0, "cpu_hours": 0.0, "cpu_hours_to_run": 0.0}
    for suite in (s for s in SUITES if s in suites):  # the script's suite order
        ids = parse_task_ids(suite, tasks)
        n = comp_trials if suite == "composition" else trials
        per: dict = {}
        for m in (x for x in METHODS if x in methods):  # the script's method order
            h, kind = ident[m]
            rows, source = book.cost(h, kind, suite, capped=max_steps is not None)
            s_trial = seconds_per_trial(m, rows, MAX_STEPS[suite], max_steps)
            count = len(ids) * n
            done = sum((h, suite, t, i) in book.keys for t in ids for i in range(n)) if h else 0
            entry = {"name": METHODS[m][0], "method": method_item(m, value_ckpt), "runs": m not in skip,
                     "trials": count, "done": done, "to_run": count - done,
                     "s_per_trial": round(s_trial, 1), "cost_source": source,
                     "cost_rows": len(rows), "cpu_hours": round(count * s_trial / 3600, 3),
                     "cpu_hours_to_run": round((count - done) * s_trial / 3600, 3)}
            if m in skip:
                entry["skipped"] = skip[m]
            else:
                for key in totals:
                    totals[key] += entry[key]
            per[m] = entry
        out_suites[suite] = {"tasks": len(ids), "trials_per_task": n, "methods": per,
                             "cpu_hours": round(sum(e["cpu_hours"] for e in per.values() if e["runs"]), 3)}
    return {"suites": out_suites,
            "trials_per_task": {"default": trials, "composition": comp_trials},
            "max_steps": max_steps, "costs_db": costs,
            "skipped": skip,
            "total_trials": totals["trials"], "total_to_run": totals["to_run"],
            "total_cpu_hours": round(totals["cpu_hours"], 2),
            "total_cpu_hours_to_run": round(totals["cpu_hours_to_run"], 2),
            "note": "CPU hours; with one trial worker (WORKERS=1) wall hours ~ CPU hours, with one worker per core "
                    "somewhat more than CPU hours / cores; totals leave out skipped "
                    "methods; defaults were measured on a shared 2-core machine (docs/results.md, docs/performance.md)"}


def libero_100_column(suite_plan: dict) -> dict:
    """The CPU hours of one more training-set column: record the demonstrations, train the VLA on them
    for as many passes as the shipped one had, and run the column's methods on the same trials as the
    tables (their per-trial costs from ``suite_plan``, the plan of the in-distribution VLA)."""
    demos = DEMOS_PER_TASK * LIBERO_100_TASKS - LIBERO_10_DEMOS_ON_HAND
    frames = DEMOS_PER_TASK * LIBERO_100_TASKS * FRAMES_PER_DEMO
    steps = EPOCHS * frames / 32
    record_h = demos * DEMO_S / 3600
    train_h = steps * 32 / TRAIN_SAMPLES_PER_S / 3600
    eval_h = sum(m["cpu_hours"] for e in suite_plan["suites"].values()
                 for name, m in e["methods"].items() if name in COLUMN_METHODS and m["runs"])
    return {"demos_to_record": demos, "record_cpu_hours": round(record_h, 1),
            "train_frames": round(frames), "train_steps": round(steps), "train_cpu_hours": round(train_h, 1),
            "frame_cache_gb": round(frames * CACHE_BYTES_PER_FRAME / 1e9, 1),
            "eval_methods": [METHODS[m][0] for m in COLUMN_METHODS], "eval_cpu_hours": round(eval_h, 1),
            "total_cpu_hours": round(record_h + train_h + eval_h, 1),
            "note": "the VLA trained on LIBERO-10 + LIBERO-90 demonstrations (50 per task, 64 px) for the shipped "
                    "recipe's ~2.1 passes; recording and training rates measured on this 2-core machine "
                    "(docs/performance.md); the frame cache is uint8 memmaps on disk, not memory"}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--costs", default=None, help="results database to take per-trial costs and finished trials from")
    p.add_argument("--suites", default=os.environ.get("SUITES", "") or ",".join(SUITES))
    p.add_argument("--methods", default=os.environ.get("METHODS", "") or ",".join(METHODS))
    p.add_argument("--tasks", default=os.environ.get("TASKS", ""), help="comma-separated task ids (default: all)")
    p.add_argument("--trials", type=int, default=_env_int("TRIALS", 3))
    p.add_argument("--comp-trials", type=int, default=_env_int("COMP_TRIALS", 5))
    p.add_argument("--max-steps", type=int, default=_env_int("MAX_STEPS", 0) or None)
    p.add_argument("--value-ckpt", default=os.environ.get("VALUE_CKPT", "") or None)
    a = p.parse_args(argv)
    if a.trials < 1 or a.comp_trials < 1:
        p.error("trials must be >= 1")
    try:
        result = plan(suites=_split(a.suites), methods=_split(a.methods), tasks=a.tasks, trials=a.trials,
                      comp_trials=a.comp_trials, max_steps=a.max_steps, value_ckpt=a.value_ckpt, costs=a.costs)
    except InvalidInput as exc:
        print(f"generalization_plan: {exc}", file=sys.stderr)
        return 2
    result["libero_100_column"] = libero_100_column(result)
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
