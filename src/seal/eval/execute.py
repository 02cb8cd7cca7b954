"""Running one trial: the code every backend (local processes, Ray actors) calls.

A `TrialRunner` lives in one worker process for many trials. It keeps the env pool of the task it
ran last (building a world costs seconds; trials of a task come in a row), and turns whatever
happens in a trial into a `TrialRow` — a crash becomes ``status='error'`` with its traceback, so
one broken trial never stops a run.
"""

from __future__ import annotations

import os
import socket
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seal.errors import InvalidInput, VerifierUnavailable
from seal.eval.store import TrialRow
from seal.eval.trials import TrialSpec

VIDEO_MODES = ("none", "failures", "all")


@dataclass(frozen=True)
class RunOptions:
    """Per-run settings that do not change results (so they are not in the config hash)."""

    out_dir: str  # traces, grids and videos go under here
    video: str = "failures"  # none | failures | all
    grids: bool = True
    pool_workers: int = 1  # simulator processes per trial worker
    max_steps: int | None = None  # cap (tests); None = the suite's limit
    pool_k: int = 1  # slots per env pool: the largest K of the run, so one pool serves every method


def trial_dir(out_dir: str | Path, spec: TrialSpec) -> Path:
    m = spec.method
    return Path(out_dir) / spec.suite / str(spec.task) / f"{m.method}-{m.config_hash}" / f"trial{spec.trial:03d}"


class TrialRunner:
    """Runs trials one after another in this process, reusing the current task's env pool."""

    def __init__(self, options: RunOptions, *, worker_name: str | None = None):
        self.options = options
        self.worker = worker_name or f"{socket.gethostname()}:{os.getpid()}"
        self._pool = None
        self._pool_key = None
        self._scorers: dict = {}

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool = self._pool_key = None

    def run(self, spec: TrialSpec) -> TrialRow:
        row = TrialRow(method=spec.method.label, config_hash=spec.method.config_hash, suite=spec.suite,
                       task=spec.task, trial=spec.trial, init_index=spec.init_index, seed=spec.seed,
                       worker=self.worker)
        start = time.perf_counter()
        out = trial_dir(self.options.out_dir, spec)
        try:
            self._run(spec, out, row)
        except KeyboardInterrupt:
            raise
        except VerifierUnavailable as exc:  # no verdict will ever come: the run must stop, not go on unverified
            row.status, row.success, row.fatal = "error", False, str(exc)
            row.error = traceback.format_exc()
        except Exception:
            row.status, row.success = "error", False
            row.error = traceback.format_exc()
            self.close()  # the pool may be in any state; build a fresh one next time
        row.wall_s = round(time.perf_counter() - start, 3)
        row.finished_at = time.time()
        return row

    def _scorer(self, path: str):
        """The V-GPS scorer of a checkpoint, loaded once per worker."""
        if path not in self._scorers:
            from seal.train.vgps import VGPSScorer

            self._scorers[path] = VGPSScorer.load(path)
        return self._scorers[path]

    def _pool_for(self, spec: TrialSpec, k: int):
        from seal.sim.pool import EnvPool
        from seal.sim.suites import get_task

        key = (spec.suite, spec.task, spec.method.render)
        if self._pool is not None and (self._pool_key != key or self._pool.k < k):
            self.close()
        if self._pool is None:
            task = get_task(spec.suite, spec.task)
            k = max(k, self.options.pool_k)
            self._pool = EnvPool(task, k=k, workers=min(self.options.pool_workers, k),
                                 render_mode=spec.method.render)
            self._pool_key = key
        return self._pool

    def _run(self, spec: TrialSpec, out: Path, row: TrialRow) -> None:
        from seal.policies.expert.policy import FailureKnobs
        from seal.sim.world import LiberoWorld
        from seal.steer.engine import Steerer, SteerConfig
        from seal.steer.run import expert_policy
        from seal.steer.trace import Trace
        from seal.verify import make_verifier

        m = spec.method
        config = SteerConfig(method=m.method, k=m.k, rounds=m.rounds, mode=m.mode, seed=spec.seed,
                             max_steps=self.options.max_steps, value_goal=m.value_goal)
        scorer = self._scorer(m.value_ckpt) if m.method == "value" else None
        pool = self._pool_for(spec, config.effective_k)
        policy = expert_policy(pool.task, FailureKnobs.named(m.knobs), seed=spec.seed)
        try:
            verifier = None if m.method != "seal" else make_verifier(
                m.verifier, model=m.model, false_positive=m.false_positive, false_negative=m.false_negative,
                seed=spec.seed)
        except InvalidInput as exc:  # e.g. no API key: every trial would fail the same way
            raise VerifierUnavailable(f"cannot build the {m.verifier!r} verifier: {exc}") from None
        out.mkdir(parents=True, exist_ok=True)
        eval_world = LiberoWorld(pool.task, render_mode=m.render) if m.mode == "replay" else None
        try:
            with Trace(out / "trace.jsonl") as trace:
                steerer = Steerer(pool, policy, verifier, config, eval_world=eval_world, trace=trace, scorer=scorer,
                                  grid_dir=out / "grids" if self.options.grids and m.method != "base" else None)
                result = steerer.run(spec.init_index)
        finally:
            if eval_world is not None:
                eval_world.close()
        row.success, row.sim_error, row.steps = result.success, result.sim_error, result.steps
        row.step_s = round(result.timing.get("predict_s", 0.0), 3)
        row.policy_s = round(result.timing.get("sampling_s", 0.0), 3)
        row.verify_wait_s = round(result.timing.get("verify_wait_s", 0.0), 3)
        row.verifier_calls, row.rounds, row.fallbacks = result.verifier_calls, result.rounds, result.fallbacks
        row.verifier_errors, row.verifier_unavailable = result.verifier_errors, result.verifier_unavailable
        row.input_tokens, row.output_tokens = result.input_tokens, result.output_tokens
        row.cost_usd = result.cost_usd
        row.subplans, row.goal_status = result.subplans, result.goal_status
        row.trace_path = str(out / "trace.jsonl")
        want_video = self.options.video == "all" or (self.options.video == "failures" and not result.success)
        if want_video and result.executed_actions:
            row.video_path = str(render_replay(pool, spec.init_index, np.array(result.executed_actions),
                                               out / "episode.mp4"))


def render_replay(pool, init_index: int, actions: np.ndarray, path: Path, *, every: int = 4, size: int = 224) -> Path:
    """Video of an executed trajectory, replayed in pool slot 0 (replays are exact, and the pool's
    world is already built, so this costs only the renders)."""
    import imageio.v2 as imageio

    pool.reset(init_index)
    with imageio.get_writer(path, fps=20 // every, macro_block_size=1) as video:
        video.append_data(_frame(pool, size))
        for i in range(0, len(actions), every):
            pool.step({0: actions[i:i + every]})
            video.append_data(_frame(pool, size))
    return path


def _frame(pool, size: int) -> np.ndarray:
    from seal.sim.observation import AGENT_CAMERA, to_policy_image

    return to_policy_image(pool.render((AGENT_CAMERA,), slots=[0])[0][AGENT_CAMERA], size)
