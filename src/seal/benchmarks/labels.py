"""`seal bench labels`: are the teacher's DAgger chunk labels what the expert actually does?

A demonstration's training chunk at frame t is a window of the actions the expert *executed*
from t on: it plans a 16-step chunk, executes 5 of them, plans afresh, and so on. A DAgger label
is asked of the expert at one state. Asked in one shot, its 16 steps extrapolate the end effector
with a model of the controller: the first 5 are what it executes, the tail need not be. Asked
closed loop (`seal.dagger.teacher_label` with the world), the expert runs on in the simulator and
the label is what it executed (then the world is restored).

This benchmark runs the clean expert from fresh sampled starts (its own seed namespace; no
rendering), keeps a snapshot at every chunk boundary and the actions it executed, and then labels
every boundary both ways: the per-step squared error of each label against the executed window
is the figure (arm dims; the gripper as the share of steps whose open/close sign differs).
"""

from __future__ import annotations

import time

import numpy as np

from seal.benchmarks.common import trials_of
from seal.errors import InvalidInput
from seal.policies.base import ACTION_HORIZON, PREDICT_HORIZON
from seal.sim.suites import get_task, parse_task_ids


def _expert_episode(world, expert, seed: int):
    """The clean expert alone, demonstration-style; (snapshots at chunk boundaries, executed actions)."""
    from seal.dagger import expert_steps

    world.reset_sampled(seed)
    expert.reset(world.instruction, seed)
    atoms = expert.privileged_atoms()
    obs = world.observe(images=False, privileged_atoms=atoms)
    snaps, actions = [], []
    for i, action in expert_steps(world, expert, obs, expert.reason(obs), atoms):
        if world.steps >= world.task.max_steps:
            break
        if i == 0:
            snaps.append((len(actions), world.snapshot()))
        actions.append(action)
    return snaps, np.asarray(actions), bool(world.success())


def _summary(err: list[np.ndarray], grip: list[np.ndarray]) -> dict:
    e = np.mean(err, axis=0)  # (PREDICT_HORIZON,)
    return {"mse_executed_prefix": round(float(e[:ACTION_HORIZON].mean()), 5),
            "mse_tail": round(float(e[ACTION_HORIZON:].mean()), 5),
            "mse_by_step": [round(float(x), 4) for x in e],
            "gripper_sign_mismatch": round(float(np.mean(grip)), 4)}


def run(args) -> dict:
    from seal.dagger import teacher_label
    from seal.demos import start_seed
    from seal.policies.expert.policy import ScriptedExpert
    from seal.sim.world import LiberoWorld

    suite = args.suite
    ids = parse_task_ids(suite, args.tasks or "0,2,5")
    n = trials_of(args, "labels")
    one_shot, closed, grip_one, grip_closed = [], [], [], []
    episodes, solved, boundaries = 0, 0, 0
    spent = {"one_shot": 0.0, "closed_loop": 0.0}  # seconds labelling, each way
    all_executed = []  # the scale the errors compare with: the executed actions' own variance
    t0 = time.perf_counter()
    for task_id in ids:
        world = LiberoWorld(get_task(suite, task_id), render_mode="fast")
        try:
            for e in range(n):
                expert = ScriptedExpert.for_world(world)
                snaps, executed, ok = _expert_episode(world, expert, start_seed(world.task.key, e, "labels"))
                episodes, solved = episodes + 1, solved + ok
                all_executed.append(executed)
                for t, snap in snaps:
                    if t + PREDICT_HORIZON > len(executed):
                        continue  # the episode ended inside this window: nothing to compare the tail with
                    window = executed[t:t + PREDICT_HORIZON]
                    for way, world_arg, err, grip in (("one_shot", None, one_shot, grip_one),
                                                      ("closed_loop", world, closed, grip_closed)):
                        world.restore(snap)
                        teacher = ScriptedExpert.for_world(world)  # nothing carried over from the episode
                        teacher.reset(world.instruction, 0)
                        obs = world.observe(images=False, privileged_atoms=teacher.privileged_atoms())
                        start = time.perf_counter()
                        label = teacher_label(teacher, obs, world_arg)
                        spent[way] += time.perf_counter() - start
                        if not label.valid:
                            continue
                        err.append(((label.chunk[:, :6] - window[:, :6]) ** 2).mean(1))
                        grip.append(np.sign(label.chunk[:, 6]) != np.sign(window[:, 6]))
                    boundaries += 1
        finally:
            world.close()
    if not closed:
        raise InvalidInput("no chunk boundary with a full 16-step window to compare: run more --trials")
    return {"benchmark": "labels", "suite": suite, "tasks": ids, "episodes": episodes, "expert_solved": solved,
            "boundaries": boundaries, "one_shot": _summary(one_shot, grip_one),
            "closed_loop": _summary(closed, grip_closed),
            "executed_action_var_arm": round(float(np.concatenate(all_executed)[:, :6].var(0).mean()), 5),
            "ms_per_label": {way: round(1000 * s / boundaries, 2) for way, s in spent.items()},
            "wall_s": round(time.perf_counter() - t0, 1)}
