"""The fast control step (seal.sim.fast_step) against robosuite's own ``env.step``, bit for bit.

Two worlds of one task, one on each step, take the same actions in lockstep from the same start:
after every step MuJoCo's full physics state (``mjSTATE_FULLPHYSICS``), the snapshot (which
adds the gripper's integrated command, the controller goal, robosuite's step counter and clock,
the camera sample) and LIBERO's success must be equal byte for byte, and the frames at the end
pixel for pixel. The actions are the scripted expert's (grasps, the stove knob, a drawer, a
microwave door) and random ones with the gripper opening and closing, from official and sampled
starts; snapshots are swapped between the two and restored both ways.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from seal.episode import run_policy_episode
from seal.policies.expert.policy import ScriptedExpert
from seal.sim.observation import AGENT_CAMERA, WRIST_CAMERA
from seal.sim.world import LiberoWorld

FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
SNAPSHOT_FIELDS = ("physics", "gripper_action", "timestep", "cur_time", "steps", "goal_ori", "goal_pos",
                   "fixtures", "view")

# whole expert episodes: the stove (knob turned at ~step 60, then the moka pot), the drawer (the
# bowl in, the drawer pushed shut at ~step 190), the book into the caddy
TASKS = (2, 3, 5)


def _full_state(world: LiberoWorld) -> bytes:
    out = np.empty(mujoco.mj_stateSize(world.model, FULL))
    mujoco.mj_getState(world.model, world.data, out, FULL)
    return out.tobytes()


def _snapshot_bytes(world: LiberoWorld) -> dict[str, bytes]:
    snap = world.snapshot()
    return {f: np.asarray(getattr(snap, f)).tobytes() for f in SNAPSHOT_FIELDS}


CONTROLLER_FIELDS = ("ee_pos", "ee_ori_mat", "ee_pos_vel", "ee_ori_vel", "joint_pos", "joint_vel", "J_pos", "J_ori",
                     "J_full", "mass_matrix", "goal_pos", "goal_ori", "torques", "new_update")


def _controller_state(world: LiberoWorld) -> dict:
    """The OSC controller's arrays: values, and the memory layout its numba-compiled functions
    specialise on (a C- rather than F-ordered matrix would run other machine code)."""
    c = world._env.robots[0].controller
    out = {}
    for name in CONTROLLER_FIELDS:
        v = np.asarray(getattr(c, name))
        out[name] = (v.tobytes(), v.dtype.str, v.shape, v.strides, v.flags.c_contiguous, v.flags.f_contiguous,
                     v.flags.writeable, v.flags.aligned)
    return out


def assert_same(stock: LiberoWorld, fast: LiberoWorld, where: str) -> None:
    assert _full_state(stock) == _full_state(fast), f"full physics state differs {where}"
    a, b = _snapshot_bytes(stock), _snapshot_bytes(fast)
    assert [f for f in SNAPSHOT_FIELDS if a[f] != b[f]] == [], f"snapshot differs {where}"
    a, b = _controller_state(stock), _controller_state(fast)
    assert [f for f in CONTROLLER_FIELDS if a[f] != b[f]] == [], f"controller state differs {where}"
    assert np.array_equal(stock._env.robots[0].torques, fast._env.robots[0].torques), where
    assert stock.success() == fast.success(), where
    assert np.array_equal(stock.model.site_rgba, fast.model.site_rgba), f"LIBERO's visual flags differ {where}"


class Lockstep:
    """``stock``'s steps and resets are repeated on ``fast`` and compared after each one."""

    def __init__(self, stock: LiberoWorld, fast: LiberoWorld):
        self.stock, self.fast, self.steps = stock, fast, 0
        step, reset, sampled = stock.step, stock.reset, stock.reset_sampled

        def paired_step(action):
            ours = step(action)
            theirs = fast.step(action)
            self.steps += 1
            assert (ours.success, ours.steps) == (theirs.success, theirs.steps)
            assert_same(stock, fast, f"after step {ours.steps} of {stock.task.key}")
            return ours

        def paired_reset(init_index=0, **kw):
            reset(init_index, **kw)
            fast.reset(init_index, **kw)
            assert_same(stock, fast, f"after reset({init_index}) of {stock.task.key}")

        def paired_sampled(seed, **kw):
            used = sampled(seed, **kw)
            assert fast.reset_sampled(seed, **kw) == used
            assert_same(stock, fast, f"after reset_sampled({seed}) of {stock.task.key}")
            return used

        stock.step, stock.reset, stock.reset_sampled = paired_step, paired_reset, paired_sampled

    def close(self) -> None:
        for name in ("step", "reset", "reset_sampled"):
            del self.stock.__dict__[name]


def random_actions(rng: np.random.Generator, n: int, hold: int = 12) -> np.ndarray:
    """Random arm motion (rotations included) with the gripper closing and opening in blocks."""
    actions = rng.uniform(-1, 1, (n, 7))
    actions[:, 6] = np.where((np.arange(n) // hold) % 2 == 0, 1.0, -1.0)
    actions[rng.random(n) < 0.1, 3:6] = 0.0  # zero rotations keep the previous goal orientation
    return actions


def assert_same_frames(stock: LiberoWorld, fast: LiberoWorld) -> None:
    a = stock.render_raw((AGENT_CAMERA, WRIST_CAMERA), size=64)
    b = fast.render_raw((AGENT_CAMERA, WRIST_CAMERA), size=64)
    for camera in (AGENT_CAMERA, WRIST_CAMERA):
        assert np.array_equal(a[camera], b[camera]), camera


def check_task(task_id: int, *, expert_steps: int | None, random_steps: int, inits=(0,), seeds=(7,)) -> int:
    """Lockstep runs of ``task_id``: the expert from official starts ``inits`` (``expert_steps``,
    None for a whole episode), then from sampled starts ``seeds`` for 60 steps followed by
    ``random_steps`` random ones; then snapshot/restore both ways. Returns the steps compared."""
    stock = LiberoWorld(("libero_10", task_id), fast_step=False)
    fast = LiberoWorld(("libero_10", task_id))
    pair = Lockstep(stock, fast)
    try:
        assert not stock.fast_step and fast.fast_step, fast.fast_step_unsupported
        rng = np.random.default_rng(task_id)
        for init in inits:  # openpi's episode start (its stale first controller step included)
            run_policy_episode(stock, ScriptedExpert.for_world(stock), init_index=init, max_steps=expert_steps)
        for seed in seeds:  # a sampled start, the expert, then random motion from where it got to
            run_policy_episode(stock, ScriptedExpert.for_world(stock), init_index=0, start_seed=seed, max_steps=60)
            stock.step_chunk(random_actions(rng, random_steps))
        assert_same_frames(stock, fast)

        # across snapshot/restore: each world's snapshot restored into both, then stepped both ways
        mid = fast.snapshot()
        actions = random_actions(rng, 20)
        for snap in (mid, stock.snapshot()):
            stock.restore(snap)
            fast.restore(snap)
            assert_same(stock, fast, "after restore")
            stock.step_chunk(actions)
        # one world, switched between the two steps around a restore
        fast.restore(mid)
        fast.step_chunk(actions)
        by_fast = (_full_state(fast), _snapshot_bytes(fast))
        fast.restore(mid)
        fast.fast_step = False
        fast.step_chunk(actions)
        fast.fast_step = True
        assert (_full_state(fast), _snapshot_bytes(fast)) == by_fast
        return pair.steps
    finally:
        pair.close()
        stock.close()
        fast.close()


def test_fast_step_is_robosuites_step_bit_for_bit():
    steps = sum(check_task(t, expert_steps=None, random_steps=60) for t in TASKS)
    assert steps >= 3 * 150


@pytest.mark.slow
@pytest.mark.parametrize("task_id", range(10))
def test_fast_step_sweep(task_id):
    """Every LIBERO-10 task: whole expert episodes from three official starts and two sampled ones."""
    check_task(task_id, expert_steps=None, random_steps=150, inits=(0, 1, 2), seeds=(11, 12))


def test_the_switch_and_what_turns_the_fast_step_off(world):
    from seal.sim.fast_step import unsupported

    assert world.fast_step and world.fast_step_unsupported == ""
    assert unsupported(world._env) == ""
    world.fast_step = False
    assert not world.fast_step
    world.fast_step = True
    assert world.fast_step
    opt = world.model.opt
    opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    try:
        assert "integrator" in unsupported(world._env)
    finally:
        opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    assert unsupported(world._env) == ""


def test_a_steered_episode_writes_the_same_trace_with_either_step(tmp_path):
    """A SEAL episode (4 candidates in one worker, so every chunk restores another slot's snapshot)
    through pools whose worlds run the stock and the fast step: the same trace but for clocks."""
    import json

    from seal.policies.expert.policy import FailureKnobs
    from seal.sim.pool import EnvPool
    from seal.sim.suites import get_task
    from seal.steer.config import SteerConfig
    from seal.steer.engine import Steerer
    from seal.steer.run import expert_policy
    from seal.steer.trace import Trace, read_trace, without_timing
    from seal.verify.oracle import OracleVerifier

    book = get_task("libero_10", 5)
    config = SteerConfig(method="seal", k=4, seed=1, max_steps=60)
    traces = {}
    for fast in (False, True):
        path = tmp_path / f"fast{int(fast)}" / "trace.jsonl"
        with EnvPool(book, k=4, workers=1, fast_step=fast) as pool, Trace(path) as trace:
            policy = expert_policy(book, FailureKnobs.misaligned(), seed=config.seed)
            result = Steerer(pool, policy, OracleVerifier(), config, trace=trace).run(0)
        assert result.steps > 0 and not result.sim_error
        traces[fast] = "\n".join(json.dumps(e, sort_keys=True) for e in without_timing(read_trace(path)))
    assert traces[True] == traces[False]
    assert traces[True].count('"event": "candidate"') >= 8
