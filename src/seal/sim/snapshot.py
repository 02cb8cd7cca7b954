"""Snapshots: everything that shapes a LIBERO world's future, small enough to send between processes.

What "everything" is was found by experiment (see tests/test_world.py):

- MuJoCo's full integration state (``mjSTATE_INTEGRATION``): time, qpos, qvel, actuator
  activations, ctrl, applied forces, mocap poses, and ``qacc_warmstart`` - the solver's warm
  start, without which replays drift by ~1e-5 within a few steps;
- the Panda gripper's ``current_action``: robosuite integrates gripper commands into it over
  time, so it is history, not a function of the physics state (~2e-4 drift without it);
- robosuite's step counter and clock (``timestep``, ``cur_time``).

- the OSC controller's goal orientation (and position): robosuite keeps the previous
  ``goal_ori`` whenever an action's rotation part is exactly zero, so the goal is history too
  (scripted policies send zero rotations all the time; random actions never do);
- where the fixtures stand: LIBERO places cabinets, racks and microwaves by moving their
  bodies in the model, differently per episode (``seal.sim.layout``), so a worker that was
  built or reset for another episode needs them to continue this one;
- the latest camera sample and robosuite's observation clock (``seal.sim.view``): images show
  the instant the clock last sampled, not the end of the step.

Restoring also marks the controller stale so it re-reads the restored pose.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Snapshot:
    task_key: str  # e.g. "libero_10/0": a snapshot only restores into the world it came from
    physics: np.ndarray  # mj_getState(..., mjSTATE_INTEGRATION)
    gripper_action: np.ndarray
    timestep: int
    cur_time: float
    steps: int = 0  # control steps of the episode so far, settle steps excluded
    goal_ori: np.ndarray | None = None  # OSC controller goal orientation (3, 3)
    goal_pos: np.ndarray | None = None  # OSC controller goal position (3,)
    fixtures: np.ndarray | None = None  # (n, 7) fixture body poses, seal.sim.layout
    view: np.ndarray | None = None  # observation clock and sample, seal.sim.view
    id: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if not self.id:
            h = hashlib.blake2b(digest_size=6)
            h.update(self.task_key.encode())
            h.update(np.ascontiguousarray(self.physics).tobytes())
            h.update(np.ascontiguousarray(self.gripper_action).tobytes())
            for extra in (self.goal_ori, self.goal_pos, self.fixtures, self.view):
                if extra is not None:
                    h.update(np.ascontiguousarray(extra).tobytes())
            h.update(f"{self.timestep}:{self.cur_time!r}:{self.steps}".encode())
            object.__setattr__(self, "id", h.hexdigest())

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Snapshot) and self.id == other.id

    def __hash__(self) -> int:
        return hash(self.id)
