"""When LIBERO's cameras look: the physics instant an observation shows.

robosuite does not observe at the end of a control step. Its observables (cameras and
proprioception alike) sample on a clock: each control step runs 25 physics substeps, the
clock advances 2 ms per substep, and a sample is taken at the first substep of every 50 ms
period; a reset and ``set_init_state`` each force one sample. After openpi's reset and init
state the clock stands at 4 ms, so every image of an episode shows the scene at the 24th
substep of its step, as positions were computed just before that substep integrated: 4 ms
before the state the step ends in. An object still falling or toppling moves visibly in 4 ms.

``ViewClock`` registers one more observable on the env, on robosuite's own clock, whose sample
is the pre-substep joint positions (what the cameras draw) and openpi's proprio readings
(end-effector position and quaternion from those positions, gripper joints after the substep,
as robosuite's sensors read them). The world renders from that sample, so a stepped world and
the package show the same frame; the sample and its clock travel in snapshots.
"""

from __future__ import annotations

import numpy as np

from seal.sim.observation import quat_xyzw_to_axis_angle

_NAME = "seal_view"


class ViewClock:
    """The latest camera sample of one LIBERO env, on robosuite's observable clock."""

    def __init__(self, env):
        from robosuite.utils.observables import Observable, sensor

        self._env = env
        data = env.sim.data
        self._nq = data.qpos.shape[0]
        self._pre_qpos = np.array(data.qpos)
        robot = env.robots[0]
        self._eef_site = robot.eef_site_id
        self._eef_body = robot.robot_model.eef_name
        self._gripper = list(robot._ref_gripper_joint_pos_indexes)

        # The substep's positions before it integrates: what its kinematics (and so a camera
        # sampled right after it) show. robosuite calls _pre_action between forward and step.
        pre_action = env._pre_action

        def remember_then_act(action, policy_step=False):
            self.remember_positions()
            return pre_action(action, policy_step)

        env._pre_action = remember_then_act

        @sensor(modality="seal")
        def view(obs_cache):
            d = env.sim.data
            wxyz = d.get_body_xquat(self._eef_body)
            return np.concatenate([self._pre_qpos, d.site_xpos[self._eef_site], wxyz[[1, 2, 3, 0]],
                                   [d.qpos[i] for i in self._gripper]])

        self._observable = Observable(name=_NAME, sensor=view, sampling_rate=env.control_freq)
        env.add_observable(self._observable)

    def remember_positions(self) -> None:
        """Keep the substep's positions before it integrates (the hook robosuite's stock step runs
        through ``_pre_action``; `seal.sim.fast_step` calls it itself)."""
        self._pre_qpos[:] = self._env.sim.data.qpos

    def tick(self, timestep: float) -> None:
        """Advance this observable's clock by one substep, sampling when due: what robosuite's
        ``_update_observables`` does for it after every substep (`seal.sim.fast_step`)."""
        self._observable.update(timestep=timestep, obs_cache=self._env._obs_cache)

    def restart(self) -> None:
        """Sample the current state as openpi's ``reset()`` then ``set_init_state()`` leave it:
        every observable's clock reset, then two forced samples."""
        env = self._env
        self._pre_qpos[:] = env.sim.data.qpos
        env._obs_cache = {}
        for observable in env._observables.values():
            observable.reset()
        for _ in range(2):
            env._update_observables(force=True)

    @property
    def qpos(self) -> np.ndarray:
        """Joint positions the cameras see."""
        return self._observable.obs[: self._nq]

    def state(self) -> np.ndarray:
        """openpi's 8-d LIBERO state at the sample: eef position, eef axis-angle, gripper joints."""
        pos, xyzw, grip = np.split(self._observable.obs[self._nq :], [3, 7])
        return np.concatenate([pos, quat_xyzw_to_axis_angle(xyzw), grip])

    def get(self) -> np.ndarray:
        """The sample and its clock as one array, for snapshots."""
        o = self._observable
        return np.concatenate([[o._time_since_last_sample, float(o._sampled)], o.obs])

    def set(self, saved: np.ndarray) -> None:
        o = self._observable
        o._time_since_last_sample, o._sampled = float(saved[0]), bool(saved[1])
        o._current_observed_value = np.array(saved[2:])
