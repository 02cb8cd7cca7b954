"""What openpi's LIBERO evaluation leaves in an env before it loads init state i.

openpi builds one env per task, seeds numpy's global RNG (``env.seed(7)``) and, for episode i,
calls ``env.reset()`` and then ``env.set_init_state(states[i])``. An official init state holds
only time, qpos and qvel, so two things from that reset live on into the episode:

- **fixture placements**: LIBERO samples where cabinets, racks and microwaves stand at every
  reset and writes them into the model (``body_pos``/``body_quat``), not into qpos;
- **the arm controller's memory of the reset pose** (LIBERO's initial joint angles plus
  robosuite's initialization noise): loading a state does not tell the controller, so the first
  control step still computes from the reset pose's end-effector pose, Jacobian and mass matrix
  and aims at the reset position; and robosuite keeps the goal orientation while an action's
  rotation part is exactly zero, as in the 10 settle steps, so the wrist turns toward that pose.

Both depend on how many resets came before: episode i starts after i + 1 of them. openpi's resets
are hard ones (the scene is recompiled each time), and LIBERO appends its object-property
samplers (drawer and door openings, stove knobs) to a list it never clears at each recompile, so
the r-th reset draws r + 1 times per sampler. ``OpenpiStarts`` replays exactly those draws, in
the same order, on soft resets (no recompile); ``tests/test_pixels.py`` checks the
result against the package's own hard-reset path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.errors import InvalidInput

OPENPI_SEED = 7  # openpi's examples/libero/main.py default


# What robosuite's OSC controller caches between updates (``Controller.update``) and its goal.
CONTROLLER_STATE = ("ee_pos", "ee_ori_mat", "ee_pos_vel", "ee_ori_vel", "joint_pos", "joint_vel",
                    "J_pos", "J_ori", "J_full", "mass_matrix", "goal_pos", "goal_ori")


@dataclass(frozen=True)
class EpisodeStart:
    """The part of an episode's start that an init state does not carry."""

    fixtures: np.ndarray  # (n, 7): position (3) and quaternion wxyz (4) of each fixture body
    controller: dict[str, np.ndarray]  # CONTROLLER_STATE at the reset pose

    def apply_controller(self, controller) -> None:
        """Leave ``controller`` as openpi's reset left it: stale until its first step."""
        for name, value in self.controller.items():
            setattr(controller, name, value.copy())
        controller.new_update = False


def fixture_bodies(env) -> list[int]:
    """Model body ids of the env's fixtures' root bodies, in a fixed (name) order."""
    model = env.sim.model
    return [model.body_name2id(env.fixtures_dict[name].root_body) for name in sorted(env.fixtures_dict)]


def read_fixtures(model, ids: list[int]) -> np.ndarray:
    """Poses of bodies ``ids`` (``fixture_bodies``) of a MuJoCo ``model``, as an (n, 7) array."""
    return np.concatenate([model.body_pos[ids], model.body_quat[ids]], axis=1)


def write_fixtures(model, ids: list[int], fixtures: np.ndarray) -> None:
    fixtures = np.asarray(fixtures, dtype=np.float64)
    if fixtures.shape != (len(ids), 7):
        raise InvalidInput(f"fixture placements must have shape ({len(ids)}, 7), got {fixtures.shape}")
    model.body_pos[ids] = fixtures[:, :3]
    model.body_quat[ids] = fixtures[:, 3:]


class NumpyGlobalRNG:
    """LIBERO's samplers draw from numpy's global RNG: run them on a state of our own, seeded once
    and carried from one ``with`` block to the next, and give the caller's state back after each."""

    def __init__(self, seed: int):
        saved = np.random.get_state()
        np.random.seed(seed)
        self.state = np.random.get_state()
        np.random.set_state(saved)

    def __enter__(self):
        self._saved = np.random.get_state()
        np.random.set_state(self.state)
        return self

    def __exit__(self, *exc):
        self.state = np.random.get_state()
        np.random.set_state(self._saved)


class OpenpiStarts:
    """Episode starts 0, 1, 2, ... of openpi's loop over one env, computed on demand and kept.

    ``env`` is LIBERO's problem env (built with ``hard_reset=False``) and is moved by the
    replayed resets: load a state after asking for a start.
    """

    def __init__(self, env, seed: int = OPENPI_SEED):
        self._env = env
        self._fixtures = fixture_bodies(env)
        self._samplers = list(env.object_property_initializers)
        self._copies = 1  # the env's constructor loaded the scene once
        self._rng = NumpyGlobalRNG(seed)
        self._starts: list[EpisodeStart] = []

    def __getitem__(self, episode: int) -> EpisodeStart:
        while len(self._starts) <= episode:
            self._starts.append(self._next())
        return self._starts[episode]

    def _next(self) -> EpisodeStart:
        from robosuite.utils.errors import RandomizationError

        env = self._env
        with self._rng:
            try:
                while True:
                    # A hard reset recompiles first, which appends one more copy of the samplers.
                    self._copies += 1
                    env.object_property_initializers = self._samplers * self._copies
                    try:
                        env.reset()
                        break
                    except RandomizationError:  # LIBERO's wrapper retries with another hard reset
                        continue
            finally:
                env.object_property_initializers = self._samplers
        controller = env.robots[0].controller
        cached = {name: np.array(getattr(controller, name), dtype=np.float64) for name in CONTROLLER_STATE}
        return EpisodeStart(read_fixtures(env.sim.model, self._fixtures), cached)


def draw_start(env, seed: int) -> tuple[np.ndarray, EpisodeStart] | None:
    """A start no evaluation uses: one soft reset of ``env`` on numpy's global RNG seeded with
    ``seed`` re-samples every object placement *and* the fixture layout with LIBERO's own
    samplers. Returns the flattened state (time, qpos, qvel) and the fixtures/controller part,
    or None when the sampler found no collision-free placement. Training data is drawn this way
    so that neither an official init state nor openpi's seed-7 layouts reach a training set.
    """
    from robosuite.utils.errors import RandomizationError

    with NumpyGlobalRNG(seed % 2**32):
        try:
            env.reset()
        except RandomizationError:
            return None
    controller = env.robots[0].controller
    cached = {name: np.array(getattr(controller, name), dtype=np.float64) for name in CONTROLLER_STATE}
    state = np.array(env.sim.get_state().flatten(), dtype=np.float64)
    return state, EpisodeStart(read_fixtures(env.sim.model, fixture_bodies(env)), cached)
