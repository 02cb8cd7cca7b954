"""One steered episode end to end: pool, policy, verifier, trace, grids, video, summary."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import imageio.v2 as imageio
import numpy as np

from seal.policies.expert.policy import FailureKnobs, ScriptedExpert
from seal.sim.observation import AGENT_CAMERA, to_policy_image
from seal.sim.pool import EnvPool
from seal.sim.suites import get_task
from seal.sim.world import LiberoWorld, PhysicsMismatch
from seal.steer.engine import Steerer, SteerConfig, SteerResult
from seal.steer.trace import Trace


def expert_policy(spec, knobs: FailureKnobs, seed: int = 0) -> ScriptedExpert:
    return ScriptedExpert(goal_atoms=spec.goal_atoms(), instruction=spec.instruction,
                          initially_open=spec.initially_open(), knobs=knobs, seed=seed, task=spec.key)


def render_executed(spec, init_index: int, actions: np.ndarray, path: Path, *, render_mode: str = "stock",
                    every: int = 2) -> Path:
    """Video of the executed trajectory, re-rendered by replaying its actions (replays are exact)."""
    world = LiberoWorld(spec, render_mode=render_mode)
    try:
        world.reset(init_index)
        with imageio.get_writer(path, fps=20 // every, macro_block_size=1) as video:
            video.append_data(to_policy_image(world.render_raw((AGENT_CAMERA,))[AGENT_CAMERA]))
            for i, action in enumerate(actions):
                world.step(action)
                if (i + 1) % every == 0:
                    video.append_data(to_policy_image(world.render_raw((AGENT_CAMERA,))[AGENT_CAMERA]))
    finally:
        world.close()
    return path


def run_steered(suite: str, task_id: int, init_index: int, out_dir: Path, *, config: SteerConfig, verifier,
                knobs: FailureKnobs, video: bool = True, grids: bool = True, mismatch: PhysicsMismatch | None = None,
                render_mode: str = "stock", workers: int | None = None, policy=None, scorer=None) -> SteerResult:
    """``policy``: any `ReasoningPolicy` (e.g. a remote `OpenpiPolicy`); default the scripted expert.
    ``scorer``: the `ChunkScorer` of the ``value`` method."""
    spec = get_task(suite, task_id)
    out_dir.mkdir(parents=True, exist_ok=True)
    policy = policy if policy is not None else expert_policy(spec, knobs, seed=config.seed)
    eval_world = LiberoWorld(spec, render_mode=render_mode) if config.mode == "replay" else None
    try:
        with EnvPool(spec, k=config.effective_k, workers=workers, render_mode=render_mode, physics=mismatch) as pool, \
                Trace(out_dir / "trace.jsonl") as trace:
            steerer = Steerer(pool, policy, verifier, config, eval_world=eval_world, trace=trace, scorer=scorer,
                              grid_dir=out_dir / "grids" if grids else None)
            result = steerer.run(init_index)
    finally:
        if eval_world is not None:
            eval_world.close()
    result.trace = str(out_dir / "trace.jsonl")
    if video and result.executed_actions:
        render_executed(spec, init_index, np.array(result.executed_actions), out_dir / "episode.mp4",
                        render_mode=render_mode)
    summary = {k: v for k, v in asdict(result).items() if k != "executed_actions"}
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    return result
