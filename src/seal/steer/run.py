"""One steered episode end to end (`seal run`): trace, candidate grids, video, summary."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from seal.steer.build import build_episode
from seal.steer.method import MethodSpec
from seal.steer.result import SteerResult


def expert_policy(task, knobs=None, seed: int = 0):
    """The scripted expert for a task (kept for scripts and tests; new code uses
    `seal.policies.make_policy("scripted", spec, task)`)."""
    from seal.policies.expert.policy import ScriptedExpert

    return ScriptedExpert.for_task(task, knobs, seed=seed)


def run_steered(spec: MethodSpec, suite: str, task_id: int, init_index: int, out_dir: Path, *, seed: int = 0,
                max_steps: int | None = None, video: bool = True, grids: bool = True, workers: int | None = None,
                subscribers=()) -> SteerResult:
    """Run ``spec`` on one init state of a task; writes trace.jsonl, grids/, episode.mp4 and
    summary.json under ``out_dir``."""
    from seal.sim.suites import get_task

    task = get_task(suite, task_id)
    out_dir = Path(out_dir)
    with build_episode(spec, task, seed=seed, out_dir=out_dir, max_steps=max_steps, grids=grids, workers=workers,
                       subscribers=subscribers) as episode:
        result = episode.run(init_index)
        if video and result.executed_actions:
            episode.replay_video(result, out_dir / "episode.mp4", every=2)
    summary = {k: v for k, v in asdict(result).items() if k != "executed_actions"}
    # what ran: the method's canonical form and store hash (as `seal eval` files it), and the verdict order,
    # which decides whether the trace repeats under load (slot) or depends on thread timing (arrival)
    summary |= {"method": spec.canonical(), "config_hash": spec.config_hash, "verify_order": spec.verify_order}
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    return result
