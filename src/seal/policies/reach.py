"""A tiny built-in action source: reach above the first goal object, descend and close.

It exists so the main command runs end to end before the scripted reasoning expert lands;
it reads the object position through the world's privileged accessor.
"""

from __future__ import annotations

import numpy as np

from seal.sim.world import LiberoWorld


class ReachPolicy:
    """Proportional delta-position control toward a target object, then a grasp."""

    def __init__(self, gain: float = 10.0):
        self.gain = gain

    def act(self, world: LiberoWorld) -> np.ndarray:
        target = world.object_position(world.goal_atoms[0].subject)
        eef = world.state_vector()[:3]
        hover = target + np.array([0.0, 0.0, 0.12])
        above = np.linalg.norm((hover - eef)[:2]) < 0.01
        goal = target + np.array([0.0, 0.0, 0.01]) if above else hover
        delta = np.clip(self.gain * (goal - eef), -1.0, 1.0)
        close = above and eef[2] - target[2] < 0.03
        return np.concatenate([delta, np.zeros(3), [1.0 if close else -1.0]])
