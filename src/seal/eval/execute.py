"""Running one trial: the code every backend (local processes, Ray actors) calls.

A `TrialRunner` lives in one worker process for many trials. It keeps the env pool of the task it
ran last (building a world costs seconds; trials of a task come in a row), and turns whatever
happens in a trial into a `TrialRow` — a crash becomes ``status='error'`` with its traceback, so
one broken trial never stops a run. The episode itself comes from `seal.steer.build`, the
builder `seal run` uses too, so a `MethodSpec` means the same thing in both.
"""

from __future__ import annotations

import os
import socket
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from seal.errors import VerifierUnavailable
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
    # robosuite's own control step instead of the bit-identical fast one (`seal.sim.fast_step`): the
    # same results, slower; for measuring what the fast step buys (`seal bench eval --stock-step`)
    stock_step: bool = False


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

    def _scorer(self, name: str, path: str):
        """A scorer (V-GPS) of a checkpoint, loaded once per worker."""
        if (name, path) not in self._scorers:
            from seal.steer.scoring import make_scorer

            self._scorers[name, path] = make_scorer(name, path)
        return self._scorers[name, path]

    def _pool_for(self, spec: TrialSpec, k: int):
        """The env pool of this trial's task, reused while trials of the same task, render model
        and physics come in a row (building one costs seconds)."""
        from seal.sim.pool import EnvPool
        from seal.sim.suites import get_task

        m = spec.method
        key = (spec.suite, spec.task, m.render, m.mismatch)
        if self._pool is not None and (self._pool_key != key or self._pool.k < k):
            self.close()
        if self._pool is None:
            task = get_task(spec.suite, spec.task)
            k = max(k, self.options.pool_k)
            self._pool = EnvPool(task, k=k, workers=min(self.options.pool_workers, k), render_mode=m.render,
                                 physics=m.physics(), fast_step=not self.options.stock_step)
            self._pool_key = key
        return self._pool

    def _run(self, spec: TrialSpec, out: Path, row: TrialRow) -> None:
        from seal.steer.build import build_episode

        m = spec.method
        pool = self._pool_for(spec, m.effective_k)
        scorer = self._scorer(m.scorer, m.scorer_checkpoint) if m.scores else None
        with build_episode(m, pool.task, seed=spec.seed, out_dir=out, pool=pool, max_steps=self.options.max_steps,
                           grids=self.options.grids and m.method != "base", scorer=scorer) as episode:
            result = episode.run(spec.init_index)
            want_video = self.options.video == "all" or (self.options.video == "failures" and not result.success)
            if want_video and result.executed_actions:
                row.video_path = str(episode.replay_video(result, out / "episode.mp4"))
        fill_row(row, result)


def fill_row(row: TrialRow, result) -> None:
    """A finished episode's `SteerResult` into its results-store row."""
    row.success, row.sim_error, row.steps = result.success, result.sim_error, result.steps
    row.ended_by = result.ended_by
    row.done_refusals = sum(not accepted for accepted in result.done_checks)
    row.step_s = round(result.timing.get("predict_s", 0.0), 3)
    row.policy_s = round(result.timing.get("sampling_s", 0.0), 3)
    row.verify_wait_s = round(result.timing.get("verify_wait_s", 0.0), 3)
    row.verifier_calls, row.rounds, row.fallbacks = result.verifier_calls, result.rounds, result.fallbacks
    row.verifier_errors, row.verifier_unavailable = result.verifier_errors, result.verifier_unavailable
    row.input_tokens, row.output_tokens = result.input_tokens, result.output_tokens
    row.cost_usd = result.cost_usd
    row.subplans, row.goal_status = result.subplans, result.goal_status
    audited = [a for a in result.aligned if a is not None]
    row.subplans_audited, row.subplans_aligned = len(audited), sum(audited)
    row.trace_path = result.trace
