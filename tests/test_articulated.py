"""The articulated-fixture primitives reach their sub-goals on real LIBERO worlds.

Each test drives one primitive from the task's initial state the way `ScriptedExpert` does:
a 16-step chunk predicted on a kinematically extrapolated scene, 5 steps executed, then a
fresh observation.
"""

import numpy as np
import pytest

from seal.policies.expert.articulated import ARTICULATED_SKILLS
from seal.policies.expert.policy import _advance
from seal.sim.goals import GoalAtom
from seal.sim.world import LiberoWorld


def _drive(world: LiberoWorld, skill: str, obj: str, atom: str, max_steps: int = 200) -> bool:
    """Run ``skill`` until it says done; whether it did within ``max_steps``."""
    fn, goal = ARTICULATED_SKILLS[skill], GoalAtom.parse(atom)
    while world.steps < max_steps:
        scene = world.scene_state([atom])
        step = fn(scene, obj, goal)
        if step.done:
            return True
        actions = [step.action]
        for _ in range(15):
            scene = _advance(scene, actions[-1])
            actions.append(fn(scene, obj, goal).action)
        actions = np.array(actions)
        assert np.all(np.abs(actions) <= 1.0)
        world.step_chunk(actions[:5])
    return False


@pytest.mark.parametrize(
    "task, skill, obj, atom",
    [
        (3, "close", "white_cabinet_1_bottom_region", "Close(white_cabinet_1_bottom_region)"),
        (2, "turn_on", "flat_stove_1", "TurnOn(flat_stove_1)"),
    ],
)
def test_primitive_reaches_its_subgoal(task, skill, obj, atom):
    world = LiberoWorld(("libero_10", task))
    try:
        world.reset(0)
        assert not world.check(atom)
        assert _drive(world, skill, obj, atom), f"{skill} {obj} did not finish"
        assert world.check(atom)
        scene = world.scene_state()
        assert -scene.eef_xmat[2, 2] > np.cos(0.1)  # handed back pointing straight down
    finally:
        world.close()
