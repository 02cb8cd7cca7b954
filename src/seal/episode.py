"""One un-steered episode of a reasoning policy: think, act in chunks, think again.

This is the `base` method (the policy alone). It records what demonstrations and reports
need: the executed frames and actions, and the step at which each sub-plan's reasoning
started and its sub-goal first held (the true critical moments).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import imageio.v2 as imageio
import numpy as np

from seal.errors import InvalidInput, SimulationError
from seal.policies.base import ACTION_HORIZON, images_for
from seal.sim.world import LiberoWorld


@dataclass
class EpisodeResult:
    task: str
    instruction: str
    init_index: int
    success: bool
    sim_error: bool
    steps: int
    wall_s: float
    subplans: list[str] = field(default_factory=list)  # the plan as first written
    critical_frames: list[int] = field(default_factory=list)  # step each sub-goal first held, -1 never
    reasoning: list[tuple[int, str]] = field(default_factory=list)  # (step, reasoning text) at each <think>
    goal_status: dict = field(default_factory=dict)
    video: str = ""
    start_seed: int | None = None  # set when the start was sampled rather than an official init state


@dataclass
class Recording:
    """Frames and actions of the executed trajectory (for datasets)."""

    agent: list = field(default_factory=list)
    wrist: list = field(default_factory=list)
    states: list = field(default_factory=list)
    actions: list = field(default_factory=list)  # float32, as datasets store them
    # the exact float64 action each control step got: a contact-rich replay reproduces the
    # episode only from these (float32-rounded actions drift, and some replays then fail)
    executed: list = field(default_factory=list)
    frames: bool = True  # False: actions and states only, no renders (re-running an episode)


def check_dart(dart) -> float:
    """A DART perturbation std as a float, or InvalidInput naming the valid range."""
    if isinstance(dart, bool) or not isinstance(dart, (int, float)) or not 0.0 <= dart <= 1.0:
        raise InvalidInput(f"--dart must be a noise std in [0, 1] (action units), got {dart!r}")
    return float(dart)


def run_policy_episode(world: LiberoWorld, policy, *, init_index: int, max_steps: int | None = None,
                       recording: Recording | None = None, video_path: Path | None = None,
                       progress=None, start_seed: int | None = None,
                       image_size: int | None = None, dart: float = 0.0) -> EpisodeResult:
    """Run ``policy`` (a ReasoningPolicy) alone for one episode; optionally record every frame.

    The episode starts from official init state ``init_index``, or, with ``start_seed``, from a
    freshly sampled start (`LiberoWorld.reset_sampled`; training data). Recorded frames are
    openpi's 224-px view, or both cameras rendered at ``image_size`` px.

    ``dart`` > 0 perturbs what is executed, not what is recorded (DART, Laskey et al. 2017): each
    executed chunk's translation and rotation get one Gaussian offset of that std, held for the
    chunk so it adds up to a displacement the next chunk has to correct, while the recording
    keeps the policy's own action at every perturbed state. Imitation then sees how the expert
    recovers from the small errors a learned policy will make."""
    dart = check_dart(dart)
    max_steps = max_steps or world.task.max_steps
    start = time.perf_counter()
    if start_seed is None:
        world.reset(init_index)
    else:
        start_seed = world.reset_sampled(start_seed)
    policy.reset(world.instruction, seed=init_index if start_seed is None else start_seed)
    noise = np.random.default_rng([init_index if start_seed is None else start_seed, 0xDA27])
    atoms = policy.privileged_atoms() if hasattr(policy, "privileged_atoms") else None
    writer = imageio.get_writer(video_path, fps=10, macro_block_size=1) if video_path else None
    result = EpisodeResult(task=world.task.key, instruction=world.instruction, init_index=init_index,
                           success=False, sim_error=False, steps=0, wall_s=0.0, video=str(video_path or ""),
                           start_seed=start_seed)
    # Recording/video wants frames (at ``image_size`` for datasets); a policy that looks at
    # images gets what it was trained on either way.
    framed = (recording is not None and recording.frames) or writer is not None
    need_images = (image_size or True) if framed else False
    wanted = images_for(policy, atoms)
    if isinstance(wanted, int) and not isinstance(wanted, bool) and need_images not in (False, wanted):
        raise InvalidInput(f"the policy sees {wanted}-px images but the recording asks for "
                           f"{'224' if need_images is True else need_images}-px frames; record at image_size={wanted}")
    need_images = wanted or need_images
    every_frame = framed
    try:
        obs = world.observe(images=need_images, privileged_atoms=atoms)
        reasoning = policy.reason(obs)
        result.subplans = list(reasoning.plans)
        result.critical_frames = [-1] * len(reasoning.plans)
        result.reasoning.append((0, reasoning.text()))
        policy.begin(1)
        while not world.success() and world.steps < max_steps and not reasoning.finished:
            chunk = policy.act([obs], reasoning)[0]
            if chunk.think:
                reasoning = policy.reason(obs)
                result.reasoning.append((world.steps, reasoning.text()))
                policy.begin(1)
                continue
            offset = np.zeros(7, dtype=np.float32)
            if dart:
                offset[:6] = noise.normal(0.0, dart, 6)  # the gripper is never perturbed
            actions = chunk.actions[:ACTION_HORIZON]
            for i, action in enumerate(actions):
                executed = np.clip(action + offset, -1.0, 1.0) if dart else action
                if recording is not None:
                    if recording.frames:
                        recording.agent.append(obs.agent)
                        recording.wrist.append(obs.wrist)
                    recording.states.append(obs.state.astype(np.float32))
                    recording.actions.append(np.asarray(action, dtype=np.float32))
                    recording.executed.append(np.array(executed, dtype=np.float64))
                if writer is not None and world.steps % 2 == 0:
                    writer.append_data(obs.agent)
                world.step(executed)
                # a policy alone looks only at the observation that ends a chunk: no renders in between
                looked_at = every_frame or i == len(actions) - 1
                obs = world.observe(images=need_images if looked_at else False, privileged_atoms=atoms)
                _mark_critical(result, obs, policy, world.steps)
                if progress is not None:
                    progress(world.steps, max_steps)
                if world.success() or world.steps >= max_steps:
                    break
    except SimulationError:
        result.sim_error = True
    finally:
        if writer is not None:
            writer.close()
    result.success = world.success() and not result.sim_error
    result.steps = world.steps
    result.goal_status = {} if result.sim_error else world.goal_status()
    result.wall_s = round(time.perf_counter() - start, 2)
    return result


def _mark_critical(result: EpisodeResult, obs, policy, step: int) -> None:
    """Record the first step at which each sub-plan's sub-goal holds, in plan order."""
    if obs.scene is None or not hasattr(policy, "plans"):
        return
    from seal.policies.expert.policy import progress as plan_progress

    done = plan_progress(policy.plans(obs.scene), obs.scene)
    for i, d in enumerate(done):
        if d and result.critical_frames[i] < 0 and all(f >= 0 for f in result.critical_frames[:i]):
            result.critical_frames[i] = step


def write_summary(result: EpisodeResult, path: Path) -> None:
    path.write_text(json.dumps(asdict(result), indent=2))
