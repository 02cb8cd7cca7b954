"""Run one episode of a task with an action source; write a video and a summary as we go."""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import imageio.v2 as imageio

from seal.errors import SimulationError
from seal.sim.world import LiberoWorld


@dataclass
class EpisodeSummary:
    task: str
    instruction: str
    init_index: int
    success: bool
    sim_error: bool
    steps: int
    goal_status: dict
    wall_s: float
    video: str


def run_episode(world: LiberoWorld, policy, *, init_index: int, out_dir: Path, max_steps: int | None = None,
                frame_every: int = 5, progress=None) -> EpisodeSummary:
    out_dir.mkdir(parents=True, exist_ok=True)
    max_steps = max_steps or world.task.max_steps
    video_path = out_dir / "episode.mp4"
    start = time.perf_counter()
    world.reset(init_index)
    success, sim_error = world.success(), False
    with imageio.get_writer(video_path, fps=20 // frame_every, macro_block_size=1) as video:
        video.append_data(world.observe().agent)
        while not success and world.steps < max_steps:
            try:
                success = world.step(policy.act(world)).success
            except SimulationError:
                sim_error = True
                break
            if world.steps % frame_every == 0:
                video.append_data(world.observe().agent)
            if progress is not None:
                progress(world.steps, max_steps)
    summary = EpisodeSummary(
        task=world.task.key, instruction=world.instruction, init_index=init_index,
        success=success and not sim_error, sim_error=sim_error, steps=world.steps,
        goal_status={} if sim_error else world.goal_status(),
        wall_s=round(time.perf_counter() - start, 2), video=str(video_path),
    )
    (out_dir / "summary.json").write_text(json.dumps(asdict(summary), indent=2))
    return summary
