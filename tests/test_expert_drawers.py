"""The scripted expert around LIBERO's wooden cabinet: bottom drawer, open drawers overhead.

Real simulator throughout (LIBERO-90 scenes); each check reads one initial state, and one
short episode opens the bottom drawer end to end.
"""

from __future__ import annotations

import numpy as np
import pytest

from seal.episode import run_policy_episode
from seal.policies.expert import articulated, skills
from seal.policies.expert.policy import FailureKnobs, ScriptedExpert
from seal.sim.world import LiberoWorld


@pytest.fixture(scope="module")
def worlds():
    made: dict[int, LiberoWorld] = {}

    def get(task: int) -> LiberoWorld:
        if task not in made:
            made[task] = LiberoWorld(("libero_90", task))
        return made[task]

    yield get
    for w in made.values():
        w.close()


def test_bottom_drawer_handle_is_too_low_for_the_level_pinch_but_the_top_one_is_not(worlds):
    w = worlds(6)  # open the bottom drawer of the cabinet
    w.reset(0)
    s = w.scene_state()
    bottom = articulated._drawer(s.articulations["wooden_cabinet_1_bottom_level"])
    top = articulated._drawer(s.articulations["wooden_cabinet_1_top_level"])
    assert bottom.handle[2] - s.table_z < articulated.LEVEL_MIN_HEIGHT <= top.handle[2] - s.table_z


def test_expert_opens_the_bottom_drawer(worlds):
    w = worlds(6)
    policy = ScriptedExpert.for_world(w, FailureKnobs.named("clean"))
    r = run_policy_episode(w, policy, init_index=0)
    assert r.success and not r.sim_error, r.goal_status
    assert r.steps < 250  # dragged out in one go (~110 steps), not by luck near the step limit


def test_bowl_in_front_of_the_closed_drawer_is_in_its_sweep(worlds):
    w = worlds(8)  # open the top drawer of the cabinet and put the bowl in it
    w.reset(0)
    s = w.scene_state()
    region = "wooden_cabinet_1_top_region"
    assert articulated.in_sweep(s, region, ("akita_black_bowl_1", "plate_1")) == "akita_black_bowl_1"
    assert articulated.in_sweep(s, region, ("plate_1",)) is None  # far out on the table
    # Opening it first pushes the bowl out of the way, with closed fingers.
    step = articulated.push_clear(s, region, "akita_black_bowl_1")
    assert step.action.shape == (7,) and step.action[6] == skills.CLOSE


def test_grasp_next_to_an_open_drawer_comes_in_from_the_side(worlds):
    w = worlds(5)  # put the chocolate pudding in the (open) top drawer and close it
    w.reset(0)
    s = w.scene_state()
    name = "chocolate_pudding_1"
    body = s.bodies[name]
    point, yaw = skills.grasp_pose(s, name, skills.Knobs())
    entry = skills._overhang_entry(s, name, body, point, yaw)
    assert entry is not None, "the open drawer hangs over the hand's footprint at the grasp"
    # At the entry the hand's footprint is clear of the drawer, and the fingertips pass over
    # the object's top while sliding in.
    part = s.articulations["wooden_cabinet_1_top_level"].part
    axis = np.array([np.cos(yaw), np.sin(yaw)])
    perp = np.array([-axis[1], axis[0]])
    corners = np.array([entry[:2] + axis * a + perp * b for a in (-skills.HAND_HALF[0], skills.HAND_HALF[0])
                        for b in (-skills.HAND_HALF[1], skills.HAND_HALF[1])])
    lo, hi = corners.min(0), corners.max(0)
    assert np.any(lo >= part.hi[:2]) or np.any(hi <= part.lo[:2])
    assert entry[2] - skills.FINGERTIP_BELOW > body.hi[2]


def test_no_side_entry_without_an_overhang(worlds):
    w = worlds(8)  # the drawer starts closed: nothing hangs over the bowl
    w.reset(0)
    s = w.scene_state()
    name = "akita_black_bowl_1"
    point, yaw = skills.grasp_pose(s, name, skills.Knobs())
    assert skills._overhang_entry(s, name, s.bodies[name], point, yaw) is None
