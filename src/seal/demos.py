"""Record scripted-expert demonstrations into a LeRobot dataset, resumably, on worker processes.

Where an episode starts:

- ``starts="sampled"`` (the default, for training data): objects *and* fixtures placed afresh by
  LIBERO's own samplers from a seed derived from the task and the episode number
  (`LiberoWorld.reset_sampled`), so no official init state and no openpi evaluation layout is
  ever in a training set; the seed actually used is kept in the episode's meta;
- ``starts="official"``: official init state e for episode e (the paper's LIBERO datasets do
  this; fine for annotation demos, never for training what is then evaluated on those states).

An episode is written only when it succeeds (like the filtered LIBERO datasets the paper
annotates), unless failures are asked for too (value learning wants them as contrast); every
attempt is logged in ``meta/seal_attempts.jsonl`` so a re-run skips it too instead of retrying
forever. Re-running the same command continues where it stopped.

Frames are openpi's 224-px view by default, or both cameras rendered directly at ``image_size``
(e.g. 64 for a policy trained at 64 px; such datasets store lossless video). With ``workers`` > 1
episodes run in that many processes (one simulator each); the writer stays in this process.
"""

from __future__ import annotations

import json
import multiprocessing
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seal.datasets import Episode, LeRobotWriter
from seal.errors import InvalidInput, SimulationError
from seal.episode import Recording, check_dart, run_policy_episode
from seal.policies.expert.policy import FailureKnobs, ScriptedExpert
from seal.sim.fast_assets import CACHE_VERSION as FAST_VERSION
from seal.sim.suites import get_task, task_count
from seal.sim.world import LiberoWorld

ATTEMPTS = "meta/seal_attempts.jsonl"
STARTS = ("sampled", "official")
SEED_STRIDE = 1000  # seeds of consecutive episodes lie this far apart (a start may skip a few draws)
BLOCK = 10  # episodes of one task recorded back to back before the next task's


@dataclass
class RecordSummary:
    recorded: int = 0
    failed: int = 0
    skipped: int = 0


@dataclass(frozen=True)
class _Job:
    suite: str
    task_id: int
    episode: int  # the init index (official starts) or the episode number (sampled starts)
    start_seed: int | None
    knobs: FailureKnobs
    render_mode: str
    image_size: int | None
    dart: float = 0.0


def start_seed(task_key: str, episode: int, namespace: str = "train") -> int:
    """First seed tried for a sampled start: stable across machines, distinct per task and episode,
    and apart from the seeds evaluation suites draw their init states from (`seal.sim.generate`).
    Another ``namespace`` (DAgger rounds) gives starts apart from the recordings'."""
    return (zlib.crc32(f"{namespace}:{task_key}".encode()) % 1_000_000) * 1_000_000 + episode * SEED_STRIDE


def _attempted(root: Path, dart: float = 0.0) -> set[tuple[str, int, int]]:
    path = root / ATTEMPTS
    if not path.is_file():
        return set()
    done = set()
    for line in path.read_text().splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue  # a torn last line after a crash: that attempt simply runs again
        if float(rec.get("dart", 0.0)) != dart:
            raise InvalidInput(f"{root} was recorded with --dart {rec.get('dart', 0.0)}, not {dart}; "
                               "resume it with the same setting or record into a new directory")
        done.add((rec["suite"], rec["task_id"], rec["init_index"]))
    return done


# One world per process, rebuilt only when the task changes (jobs come sorted by task).
_WORLD: dict = {}


def _run_job(job: _Job) -> tuple[_Job, dict, Episode | None]:
    world = _WORLD.get("world")
    if world is None or world.task.key != get_task(job.suite, job.task_id).key or world.render_mode != job.render_mode:
        if world is not None:
            world.close()
        world = _WORLD["world"] = LiberoWorld(get_task(job.suite, job.task_id), render_mode=job.render_mode)
    policy = ScriptedExpert.for_world(world, job.knobs)
    rec = Recording()
    result = run_policy_episode(world, policy, init_index=job.episode, recording=rec,
                                start_seed=job.start_seed, image_size=job.image_size, dart=job.dart)
    attempt = {"suite": job.suite, "task_id": job.task_id, "init_index": job.episode, "success": result.success,
               "steps": result.steps, "sim_error": result.sim_error, "start_seed": result.start_seed,
               "dart": job.dart}
    if not rec.actions:
        return job, attempt, None
    episode = Episode(
        instruction=world.instruction,
        agent_images=np.stack(rec.agent), wrist_images=np.stack(rec.wrist),
        states=np.stack(rec.states), actions=np.clip(np.stack(rec.actions), -1, 1),
        subplans=result.subplans,
        # critical frames are steps after which the sub-goal held; as frame indices
        # they point at the frame observed right after that step
        critical_frames=[min(f, len(rec.actions) - 1) if f >= 0 else -1 for f in result.critical_frames],
        meta={"suite": job.suite, "task_id": job.task_id, "init_index": job.episode,
              "start": "official" if job.start_seed is None else "sampled", "start_seed": result.start_seed,
              "render_mode": job.render_mode, "image_size": job.image_size or 224,
              # the fast model's meshes change between versions; a policy trained on them is evaluated in the same
              "fast_version": FAST_VERSION if job.render_mode == "fast" else None,
              "steps": result.steps, "success": bool(result.success), "knobs": job.knobs.__dict__,
              # executed chunks were perturbed by this std; recorded actions are the expert's own
              "dart": job.dart,
              # what the expert wrote at each <think>: (step, text) pairs
              "reasoning": [[int(s), t] for s, t in result.reasoning]},
    )
    return job, attempt, episode


def _close_world() -> None:
    world = _WORLD.pop("world", None)
    if world is not None:
        world.close()


def record_demos(suite: str, out: Path, *, episodes_per_task: int, tasks: list[int] | None = None,
                 knobs: FailureKnobs | None = None, progress=None, render_mode: str = "stock",
                 keep_failures: bool = False, starts: str = "sampled", image_size: int | None = None,
                 workers: int = 1, dart: float = 0.0) -> RecordSummary:
    """Record expert episodes; ``keep_failures`` also writes failed ones (meta ``success`` False),
    which offline RL (the V-GPS value function) needs as contrast to the successes. ``dart``:
    perturb the executed chunks, record the expert's actions (`run_policy_episode`)."""
    if starts not in STARTS:
        raise InvalidInput(f"unknown starts {starts!r}; valid: {', '.join(STARTS)}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InvalidInput(f"workers must be a positive integer, got {workers!r}")
    tasks = list(range(task_count(suite))) if tasks is None else tasks
    specs = [get_task(suite, t) for t in tasks]  # validates every id before any work
    for spec in specs:
        n = spec.init_states().shape[0] if starts == "official" else 10_000
        if not 1 <= episodes_per_task <= n:
            raise InvalidInput(f"{spec.key} has {n} init states; --episodes-per-task must be in 1..{n}, "
                               f"got {episodes_per_task}")
    dart = check_dart(dart)
    knobs = knobs or FailureKnobs()
    out.mkdir(parents=True, exist_ok=True)
    summary = RecordSummary()
    attempted = _attempted(out, dart)  # refuses a resume with other settings before any work
    with LeRobotWriter(out, fps=20, image_size=image_size or 224) as writer:
        jobs = []
        for spec in specs:
            todo = [e for e in range(episodes_per_task) if (suite, spec.task_id, e) not in attempted]
            summary.skipped += episodes_per_task - len(todo)
            if progress:
                progress(spec, summary, advance=episodes_per_task - len(todo))
            jobs += [_Job(suite, spec.task_id, e, None if starts == "official" else start_seed(spec.key, e),
                          knobs, render_mode, image_size, dart) for e in todo]
        # Blocks of BLOCK episodes per task, task after task, then the next block: a recording
        # stopped early (or read while it runs) holds every task about equally, and a worker
        # rebuilds its world only once per block.
        jobs.sort(key=lambda j: (j.episode // BLOCK, tasks.index(j.task_id), j.episode))

        def finish(job: _Job, attempt: dict, episode: Episode | None) -> None:
            if episode is not None and (attempt["success"] or keep_failures):
                writer.add(episode)
                summary.recorded += 1
            summary.failed += not attempt["success"]
            with open(out / ATTEMPTS, "a") as f:  # after the episode: a crash between redoes it
                f.write(json.dumps(attempt) + "\n")
            if progress:
                progress(get_task(suite, job.task_id), summary, advance=1)

        if workers == 1:
            try:
                for job in jobs:
                    finish(*_run_job(job))
            finally:
                _close_world()
        else:
            _run_parallel(jobs, workers, finish)
    return summary


def _run_parallel(jobs: list[_Job], workers: int, finish) -> None:
    # Spawned workers: a forked MuJoCo/EGL context is not safe to reuse. Each worker keeps its
    # world between jobs, and jobs go out in order (one at a time), so worlds are rarely rebuilt.
    # Leaving the ``with`` block terminates the workers, also on Ctrl-C or SIGTERM: episodes in
    # flight are dropped, everything finished is already written.
    from seal.sim.pool import ignore_interrupts

    with multiprocessing.get_context("spawn").Pool(workers, initializer=ignore_interrupts) as pool:
        for result in pool.imap_unordered(_run_job, jobs, chunksize=1):
            finish(*result)


def exact_actions(world, meta: dict, recorded: np.ndarray) -> np.ndarray | None:
    """The float64 actions the scripted expert executed in a recorded demonstration (``meta``: its
    dataset meta; ``recorded``: its stored float32 actions), by running it again from the same start
    in ``world`` (it is deterministic, and no frame is rendered); None where that cannot be the
    recording: a DART demonstration (its executed actions were perturbed), one without the expert's
    settings, or a re-run whose float32 actions differ from the stored ones. Datasets store float32,
    and a contact-rich replay of rounded actions drifts (`seal verify from-demos` uses this)."""
    m = meta.get("meta") or {}
    if m.get("dart") or not isinstance(m.get("knobs"), dict) or "start_seed" not in m:
        return None
    rec = Recording(frames=False)
    try:
        run_policy_episode(world, ScriptedExpert.for_world(world, FailureKnobs(**m["knobs"])),
                           init_index=int(m.get("init_index", 0)), recording=rec, start_seed=int(m["start_seed"]),
                           max_steps=len(recorded))
    except (SimulationError, TypeError):  # TypeError: knobs of another version of the expert
        return None
    if len(rec.executed) != len(recorded):
        return None
    stored = np.clip(np.stack(rec.actions), -1, 1).astype(np.float64)
    if not np.array_equal(stored, recorded):
        return None
    return np.stack(rec.executed)
