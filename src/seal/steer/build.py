"""From a `MethodSpec` to a running episode: the one place that wires policy, pool, verifier,
scorer, evaluation world and subscribers together.

`seal run` (`seal.steer.run.run_steered`), `seal eval` (`seal.eval.execute.TrialRunner`) and
`seal bench steer|runtime` all build their episodes here, so a method means the same thing in
each of them. Plug-ins come from the registries: `seal.policies.make_policy`,
`seal.verify.verifier_for`, `seal.steer.scoring.make_scorer`.
"""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

from seal.errors import InvalidInput, VerifierUnavailable
from seal.policies import make_policy
from seal.steer.engine import Steerer
from seal.steer.method import MethodSpec
from seal.steer.result import SteerResult
from seal.steer.scoring import make_scorer
from seal.steer.trace import Trace
from seal.steer.video import replay_video
from seal.verify import verifier_for


class Episode:
    """A ready `Steerer` plus everything it holds; close it (or use ``with``) to release them.

    A pool passed in is borrowed (the caller reuses it across episodes); anything built here is
    owned and closed here.
    """

    def __init__(self, steerer: Steerer, task, spec: MethodSpec, out_dir: Path | None, stack: ExitStack):
        self.steerer, self.task, self.spec, self.out_dir = steerer, task, spec, out_dir
        self._stack = stack

    @property
    def pool(self):
        return self.steerer.pool

    @property
    def trace_path(self) -> Path | None:
        return None if self.out_dir is None else self.out_dir / "trace.jsonl"

    def run(self, init_index: int) -> SteerResult:
        result = self.steerer.run(init_index)
        if self.trace_path is not None:
            result.trace = str(self.trace_path)
        return result

    def replay_video(self, result: SteerResult, path: Path, *, every: int = 4) -> Path:
        """The executed trajectory re-rendered where it really happened: the evaluation world in
        replay mode, else the pool (replays are exact, so this costs only the renders)."""
        world = self.steerer.eval_world if self.spec.mode == "replay" else self.pool
        return replay_video(world, result.init_index, result.executed_actions, path, every=every)

    def close(self) -> None:
        self._stack.close()

    def __enter__(self) -> "Episode":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def build_episode(spec: MethodSpec, task, *, seed: int = 0, out_dir: str | Path | None = None, pool=None,
                  max_steps: int | None = None, grids: bool = True, workers: int | None = None,
                  policy=None, verifier=None, scorer=None, subscribers=()) -> Episode:
    """The episode ``spec`` describes on ``task`` (a `TaskSpec`).

    ``out_dir``: trace (and grids) go there; None writes nothing. ``pool``: an `EnvPool` of the
    task with at least K slots to reuse (its physics must be the spec's). ``policy`` /
    ``verifier`` / ``scorer``: already-built plug-ins to use instead of the spec's (a benchmark's
    delayed oracle, a worker's cached scorer); the caller keeps ownership of those.
    """
    from seal.sim.pool import EnvPool
    from seal.sim.world import LiberoWorld

    config = spec.steer_config(seed=seed, max_steps=max_steps)
    stack = ExitStack()
    try:
        if pool is None:
            pool = stack.enter_context(EnvPool(task, k=spec.effective_k, workers=workers, render_mode=spec.render,
                                               physics=spec.physics()))
        if verifier is None:
            try:
                verifier = verifier_for(spec, seed=seed)
            except InvalidInput as exc:  # e.g. no API key: no verdict would ever come, so a run must stop
                raise VerifierUnavailable(f"cannot build the {spec.verifier!r} verifier: {exc}") from None
        if scorer is None and spec.scores:
            scorer = make_scorer(spec.scorer, spec.scorer_checkpoint)
        if policy is None:
            policy = make_policy(spec.policy, spec.policy_options, task, seed=seed)
            stack.callback(policy.close)
        eval_world = None
        if spec.mode == "replay":  # the "real" world the winners' actions are executed in
            eval_world = LiberoWorld(task, render_mode=spec.render)
            stack.callback(eval_world.close)
        trace = grid_dir = None
        if out_dir is not None:
            out_dir = Path(out_dir)
            out_dir.mkdir(parents=True, exist_ok=True)
            trace = stack.enter_context(Trace(out_dir / "trace.jsonl"))
            grid_dir = out_dir / "grids" if grids else None
        steerer = Steerer(pool, policy, verifier, config, eval_world=eval_world, trace=trace, grid_dir=grid_dir,
                          scorer=scorer, subscribers=tuple(subscribers))
    except BaseException:
        stack.close()
        raise
    return Episode(steerer, task, spec, out_dir, stack)
