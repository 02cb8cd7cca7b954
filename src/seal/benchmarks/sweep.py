"""`seal bench verifier-sweep`: how good must a verifier be? SEAL's success against the noisy
verifier's false-positive x false-negative rates, on fixed tasks and seeds.

Every grid cell runs the same (task, trial) episodes: trial t of a task starts from official
init state ``t mod #inits`` with seed `seal.eval.trials.trial_seed` (as `seal eval` does), so
cells differ only in the verifier's error rates. The policy alone (``base``) runs the same
trials once, as the floor. Rows go to ``OUT/results.jsonl`` as episodes finish; a re-run skips
the rows it finds there. At the end: ``OUT/sweep.md`` (table) and ``OUT/sweep.png`` (success
over the grid as a heat map, with measured verifiers drawn at their (FP rate, FN rate); and
success against the FP rate, one line per FN rate). ``--points`` takes `seal bench verifier`
JSON outputs (files) to draw as measured points.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from seal.benchmarks.common import trials_of
from seal.errors import InvalidInput

DEFAULT_FP = (0.0, 0.1, 0.2, 0.4)
DEFAULT_FN = (0.0, 0.2, 0.4)
DEFAULT_OUT = Path("runs") / "verifier" / "sweep"


def _rates(text: str | None, default: tuple[float, ...], what: str) -> tuple[float, ...]:
    if not text:
        return default
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise InvalidInput(f"{what} wants comma-separated rates in [0, 1], got {text!r}") from None
    if not values or any(not 0.0 <= v <= 1.0 for v in values):
        raise InvalidInput(f"{what} wants comma-separated rates in [0, 1], got {text!r}")
    return values


def _key(row: dict) -> tuple:
    return (row["cell"], row["task"], row["trial"])


def read_rows(path: Path) -> list[dict]:
    rows = []
    if path.is_file():
        for line in path.read_text().splitlines():
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:  # a half-written last line of an interrupted run
                continue
    return rows


def cell_name(fp: float, fn: float) -> str:
    return f"fp={fp:g},fn={fn:g}"


def run(args) -> dict:
    from seal.eval.trials import trial_seed
    from seal.sim.pool import EnvPool
    from seal.sim.suites import get_task, parse_task_ids
    from seal.steer.build import build_episode
    from seal.steer.method import MethodSpec

    fps = _rates(getattr(args, "fp", None), DEFAULT_FP, "--fp")
    fns = _rates(getattr(args, "fn", None), DEFAULT_FN, "--fn")
    trials = trials_of(args, "verifier-sweep")
    tasks = parse_task_ids(args.suite, args.tasks or "0,1,7")
    # read before any episode runs (a bad file found after an hour's sweep wastes the hour)
    points = load_points(getattr(args, "points", None))
    if args.k < 1:
        raise InvalidInput(f"--k must be >= 1, got {args.k}")
    if args.workers is not None and not 1 <= args.workers <= args.k:
        raise InvalidInput(f"--workers must be in 1..{args.k} for --k {args.k}, got {args.workers}")
    out = Path(args.out) if getattr(args, "out", None) else DEFAULT_OUT
    policy = getattr(args, "policy", None) or "scripted"
    knobs = "misaligned" if policy == "scripted" else None  # the scripted expert's setting (recorded for it only)
    common = {"k": args.k, "knobs": "misaligned", "policy": policy}
    cells = {"base": MethodSpec(method="base", **common)}
    for fp in fps:
        for fn in fns:
            cells[cell_name(fp, fn)] = MethodSpec(method="seal", verifier="noisy", false_positive=fp,
                                                  false_negative=fn, **common)
    settings = {"suite": args.suite, "k": args.k, "policy": policy, "knobs": knobs,
                "max_steps": getattr(args, "max_steps", None)}
    settings_path = out / "settings.json"
    out.mkdir(parents=True, exist_ok=True)  # after every check: a refused sweep leaves no empty folder
    if settings_path.is_file() and json.loads(settings_path.read_text()) != settings:
        raise InvalidInput(f"{out} holds a sweep with other settings ({settings_path.read_text().strip()}; now "
                           f"{json.dumps(settings)}); use another --out")
    settings_path.write_text(json.dumps(settings))
    results = out / "results.jsonl"
    done = {_key(r) for r in read_rows(results)}
    ran = 0
    with open(results, "a") as log:
        for t in tasks:
            task = get_task(args.suite, t)
            todo = [(name, trial) for trial in range(trials) for name in cells
                    if (name, task.key, trial) not in done]
            if not todo:
                continue
            n_inits = len(task.init_states())
            with EnvPool(task, k=args.k, workers=args.workers) as pool:
                for name, trial in todo:
                    spec, seed = cells[name], trial_seed(args.suite, t, trial)
                    with build_episode(spec, task, seed=seed, pool=pool, max_steps=getattr(args, "max_steps", None),
                                       grids=False) as episode:
                        r = episode.run(trial % n_inits)
                    rates = spec.verifier_options
                    row = {"cell": name, "fp": rates.false_positive if name != "base" else None,
                           "fn": rates.false_negative if name != "base" else None, "task": task.key,
                           "trial": trial, "init": trial % n_inits, "seed": seed, "success": bool(r.success),
                           "steps": r.steps, "verifier_calls": r.verifier_calls, "fallbacks": r.fallbacks}
                    log.write(json.dumps(row) + "\n")
                    log.flush()
                    ran += 1
    rows = [r for r in read_rows(results) if r["cell"] in cells and r["task"] in {get_task(args.suite, t).key for t in tasks}
            and r["trial"] < trials]
    table = summarize(rows, fps, fns)
    md = markdown(table, fps, fns, points, policy)
    (out / "sweep.md").write_text(md)
    plot = draw(table, fps, fns, points, out / "sweep.png")
    return {"suite": args.suite, "tasks": tasks, "trials": trials, "k": args.k, "policy": policy,
            "knobs": knobs, "max_steps": getattr(args, "max_steps", None), "episodes_run": ran,
            "base_success": table["base"], "grid": {name: table["cells"][name] for name in table["cells"]},
            "points": points, "results": str(results), "markdown": str(out / "sweep.md"), "plot": str(plot)}


def summarize(rows: list[dict], fps, fns) -> dict:
    def mean(name):
        xs = [r["success"] for r in rows if r["cell"] == name]
        return {"success": round(float(np.mean(xs)), 3) if xs else None, "episodes": len(xs)}

    return {"base": mean("base"), "cells": {cell_name(fp, fn): mean(cell_name(fp, fn)) for fp in fps for fn in fns}}


def load_points(text: str | None) -> list[dict]:
    """(label, fp_rate, fn_rate) of measured verifiers, from `seal bench verifier` JSON files."""
    points = []
    for item in filter(None, (s.strip() for s in (text or "").split(","))):
        path = Path(item)
        try:
            result = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise InvalidInput(f"--points: cannot read {path} as a `seal bench verifier` JSON: {exc}") from None
        if not isinstance(result, dict) or result.get("fp_rate") is None or result.get("fn_rate") is None:
            raise InvalidInput(f"--points: {path} has no fp_rate / fn_rate (not a `seal bench verifier` output?)")
        for key in ("fp_rate", "fn_rate"):
            v = result[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
                raise InvalidInput(f"--points: {path} has {key} {v!r}; a rate is a number in [0, 1]")
        label = str(result.get("verifier", path.stem))
        if ":" in label and "/" in label:  # learned:/long/path/RUN -> learned:RUN
            kind, _, where = label.partition(":")
            # the shipped checkpoint's directory is named for its kind: learned:.../learned -> learned
            label = kind if Path(where).name == kind else f"{kind}:{Path(where).name}"
        points.append({"label": label, "fp_rate": result["fp_rate"],
                       "fn_rate": result["fn_rate"], "cases": result.get("cases")})
    return points


def markdown(table: dict, fps, fns, points, policy: str = "scripted") -> str:
    base = table["base"]["success"]
    who = "misaligned expert" if policy == "scripted" else policy
    text = (f"SEAL success ({who}) by the noisy verifier's error rates; policy alone: "
            f"{'-' if base is None else f'{base:.3f}'} ({table['base']['episodes']} episodes).\n\n")
    text += "| FN rate \\ FP rate | " + " | ".join(f"{fp:g}" for fp in fps) + " |\n"
    text += "| --- |" + " ---: |" * len(fps) + "\n"
    for fn in fns:
        cells = [table["cells"][cell_name(fp, fn)] for fp in fps]
        text += f"| {fn:g} | " + " | ".join("-" if c["success"] is None else f"{c['success']:.3f} ({c['episodes']})"
                                           for c in cells) + " |\n"
    if points:
        text += "\nMeasured verifiers (from `seal bench verifier`):\n\n| verifier | FP rate | FN rate | cases |\n"
        text += "| --- | ---: | ---: | ---: |\n"
        for p in points:
            text += f"| {p['label']} | {p['fp_rate']:.3f} | {p['fn_rate']:.3f} | {p['cases']} |\n"
    return text


def _edges(values) -> np.ndarray:
    v = np.asarray(sorted(values), dtype=float)
    if len(v) == 1:
        return np.array([v[0] - 0.05, v[0] + 0.05])
    mid = (v[1:] + v[:-1]) / 2
    return np.concatenate([[v[0] - (mid[0] - v[0])], mid, [v[-1] + (v[-1] - mid[-1])]])


def plot_limits(edges, values) -> tuple[float, float]:
    """Axis range that holds the grid's cell edges and every measured point, with room for a label
    on the high side."""
    lo, hi = min(*edges, *values), max(*edges, *values)
    return lo, hi + 0.12 * max(hi - lo, 0.1)


def draw(table: dict, fps, fns, points, path: Path) -> Path:
    """Heat map over the FP x FN grid with the measured verifiers as stars, and success against the
    rate the sweep varies."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fps_s, fns_s = sorted(fps), sorted(fns)
    grid = np.full((len(fns_s), len(fps_s)), np.nan)
    for i, fn in enumerate(fns_s):
        for j, fp in enumerate(fps_s):
            s = table["cells"][cell_name(fp, fn)]["success"]
            grid[i, j] = np.nan if s is None else s
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    # Cells span the midpoints between grid values, clipped to [0, 1]: a measured verifier sits in
    # the cell of the nearest grid point.
    xe, ye = np.clip(_edges(fps_s), 0, 1), np.clip(_edges(fns_s), 0, 1)
    mesh = ax.pcolormesh(xe, ye, grid, cmap="viridis", vmin=0, vmax=1)
    for i in range(len(fns_s)):
        for j in range(len(fps_s)):
            if not np.isnan(grid[i, j]):
                ax.text((xe[j] + xe[j + 1]) / 2, (ye[i] + ye[i + 1]) / 2, f"{grid[i, j]:.2f}", ha="center",
                        va="center", color="black" if grid[i, j] > 0.6 else "white", fontsize=9)
    for p in points:
        ax.plot(p["fp_rate"], p["fn_rate"], marker="*", markersize=11, color="red", markeredgecolor="black",
                clip_on=False, zorder=5)
        ax.annotate(p["label"], (p["fp_rate"], p["fn_rate"]), textcoords="offset points", xytext=(6, 6),
                    fontsize=8, color="red")
    # The measured points may lie outside the grid (one FP column, a verifier at FP 0.29): widen the
    # axes to show them with their labels, never crop the grid.
    ax.set_xlim(*plot_limits(xe, [p["fp_rate"] for p in points]))
    ax.set_ylim(*plot_limits(ye, [p["fn_rate"] for p in points]))
    ax.set_xlabel("false-positive rate")
    ax.set_ylabel("false-negative rate")
    ax.set_title("SEAL success by verifier error rates")
    fig.colorbar(mesh, ax=ax, label="success rate")
    # Success against whichever rate the sweep varies: FP (one line per FN rate) unless only FN varies.
    along_fn = len(fps_s) == 1 and len(fns_s) > 1
    if along_fn:
        ax2.plot(fns_s, grid[:, 0], "o-", label=f"FP rate {fps_s[0]:g}")
    else:
        for i, fn in enumerate(fns_s):
            ax2.plot(fps_s, grid[i], "o-", label=f"FN rate {fn:g}")
    base = table["base"]["success"]
    if base is not None:
        ax2.axhline(base, color="gray", linestyle="--", label="policy alone")
    ax2.set_xlabel("false-negative rate" if along_fn else "false-positive rate")
    ax2.set_ylabel("success rate")
    ax2.set_ylim(-0.02, 1.02)
    ax2.grid(alpha=0.3)
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
