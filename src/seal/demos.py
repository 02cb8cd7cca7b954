"""Record scripted-expert demonstrations into a LeRobot dataset, resumably.

Episode e of task t starts from official init state e. An episode is written only when it
succeeds (like the filtered LIBERO datasets the paper annotates), unless failures are asked for
too (value learning wants them as contrast); every attempt is logged in
``meta/seal_attempts.jsonl`` so a re-run skips it too instead of retrying forever. Re-running the
same command continues where it stopped.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seal.datasets import Episode, LeRobotWriter
from seal.errors import InvalidInput
from seal.episode import Recording, run_policy_episode
from seal.policies.expert.policy import FailureKnobs, ScriptedExpert
from seal.sim.suites import get_task, task_count
from seal.sim.world import LiberoWorld

ATTEMPTS = "meta/seal_attempts.jsonl"


@dataclass
class RecordSummary:
    recorded: int = 0
    failed: int = 0
    skipped: int = 0


def _attempted(root: Path) -> set[tuple[str, int, int]]:
    path = root / ATTEMPTS
    if not path.is_file():
        return set()
    done = set()
    for line in path.read_text().splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue  # a torn last line after a crash: that attempt simply runs again
        done.add((rec["suite"], rec["task_id"], rec["init_index"]))
    return done


def record_demos(suite: str, out: Path, *, episodes_per_task: int, tasks: list[int] | None = None,
                 knobs: FailureKnobs | None = None, progress=None, render_mode: str = "stock",
                 keep_failures: bool = False) -> RecordSummary:
    """Record expert episodes; ``keep_failures`` also writes failed ones (meta ``success`` False),
    which offline RL (the V-GPS value function) needs as contrast to the successes."""
    tasks = list(range(task_count(suite))) if tasks is None else tasks
    specs = [get_task(suite, t) for t in tasks]  # validates every id before any work
    for spec in specs:
        n = spec.init_states().shape[0]
        if not 1 <= episodes_per_task <= n:
            raise InvalidInput(f"{spec.key} has {n} init states; --episodes-per-task must be in 1..{n}, "
                               f"got {episodes_per_task}")
    out.mkdir(parents=True, exist_ok=True)
    summary = RecordSummary()
    with LeRobotWriter(out, fps=20) as writer:
        attempted = _attempted(out)
        for spec in specs:
            todo = [e for e in range(episodes_per_task) if (suite, spec.task_id, e) not in attempted]
            summary.skipped += episodes_per_task - len(todo)
            if progress:
                progress(spec, summary, advance=episodes_per_task - len(todo))
            if not todo:
                continue
            world = LiberoWorld(spec, render_mode=render_mode)
            policy = ScriptedExpert.for_world(world, knobs)
            try:
                for e in todo:
                    rec = Recording()
                    result = run_policy_episode(world, policy, init_index=e, recording=rec)
                    if result.success or keep_failures:
                        writer.add(Episode(
                            instruction=spec.instruction,
                            agent_images=np.stack(rec.agent), wrist_images=np.stack(rec.wrist),
                            states=np.stack(rec.states), actions=np.clip(np.stack(rec.actions), -1, 1),
                            subplans=result.subplans,
                            # critical frames are steps after which the sub-goal held; as frame indices
                            # they point at the frame observed right after that step
                            critical_frames=[min(f, len(rec.actions) - 1) if f >= 0 else -1
                                             for f in result.critical_frames],
                            meta={"suite": suite, "task_id": spec.task_id, "init_index": e,
                                  "steps": result.steps, "success": bool(result.success),
                                  "knobs": (knobs or FailureKnobs()).__dict__,
                                  # what the expert wrote at each <think>: (step, text) pairs
                                  "reasoning": [[int(s), t] for s, t in result.reasoning]},
                        ))
                        summary.recorded += 1
                    summary.failed += not result.success
                    with open(out / ATTEMPTS, "a") as f:
                        f.write(json.dumps({"suite": suite, "task_id": spec.task_id, "init_index": e,
                                            "success": result.success, "steps": result.steps,
                                            "sim_error": result.sim_error}) + "\n")
                    if progress:
                        progress(spec, summary, advance=1)
            finally:
                world.close()
    return summary
