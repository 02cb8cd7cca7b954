"""The frying pan family of LIBERO-90: where the expert holds a pan, and the geometry of the
shelf level it slides one into, read from real worlds (task 42: the pan in front of the
wooden two-layer shelf); and the expert solving task 42 end to end (the hardest: under the
shelf's middle board)."""

import numpy as np
import pytest
from _worlds import world_at

from seal.episode import run_policy_episode
from seal.policies.expert import pan, shelf_slide, skills
from seal.policies.expert.policy import FailureKnobs, ScriptedExpert

PAN = "chefmate_8_frypan_1"
BOTTOM, TOP = "wooden_two_layer_shelf_1_bottom_region", "wooden_two_layer_shelf_1_top_region"


@pytest.fixture(scope="module")
def shelf_world():
    with world_at("libero_90", 42) as w:
        yield w


def test_pan_is_held_across_its_handle_not_over_its_dish(shelf_world):
    s = shelf_world.scene_state()
    body = s.bodies[PAN]
    # The handle points +y (out of the shelf's open side) in this task.
    assert pan.handle_direction(PAN, body) @ np.array([0.0, 1.0]) > 0.99
    point, yaw = skills.grasp_pose(s, PAN, skills.Knobs())
    assert abs(np.cos(yaw)) > 0.85  # finger axis within 30 degrees of across the handle (x)
    assert point[1] - body.pos[1] > 0.13  # out on the handle, past the dish's rim (~9.7 cm)
    assert body.pos[2] + 0.03 < point[2] < body.hi[2]  # at the handle's height, above the table
    assert not pan.is_pan("akita_black_bowl_1") and pan.handle_grasps(s, "white_bowl_1") == []


def test_shelf_levels_are_read_from_the_scene(shelf_world):
    s = shelf_world.scene_state()
    bottom, top = shelf_slide.level(s, PAN, BOTTOM), shelf_slide.level(s, PAN, TOP)
    assert bottom is not None and top is not None
    assert bottom.out @ np.array([0.0, 1.0]) > 0.99  # open toward +y (the back board is at -y)
    assert abs(bottom.floor - s.table_z) < 0.005  # the bottom level stands on the table
    assert abs(top.floor - 0.99) < 0.01  # the top level on the middle board
    assert bottom.depth(s.sites[BOTTOM].pos) > 0.05  # the region lies inside the front face
    assert bottom.depth(s.bodies[PAN].pos) < -0.1  # the pan starts out in front of it
    # Not slid in: the shelf's roof (placed on from above), a non-pan object, a table region.
    assert shelf_slide.level(s, PAN, "wooden_two_layer_shelf_1_top_side") is None
    assert shelf_slide.level(s, "white_bowl_1", BOTTOM) is None
    assert shelf_slide.level(s, PAN, "flat_stove_1_cook_region") is None


def test_expert_slides_the_pan_under_the_shelf(shelf_world):
    policy = ScriptedExpert.for_world(shelf_world, FailureKnobs.named("clean"))
    result = run_policy_episode(shelf_world, policy, init_index=0)
    assert result.success, result.goal_status
    assert shelf_world.check(f"In({PAN}, {BOTTOM})")


def test_a_drooping_pan_is_let_go_and_a_level_one_lifted_slowly(shelf_world):
    from dataclasses import replace

    s = shelf_world.scene_state()
    held = replace(s, facts={**s.facts, f"Grasped({PAN})": True})
    level = skills.pick(held, PAN, skills.Knobs())
    assert level.action[6] == skills.CLOSE and 0 < level.action[2] <= pan.LIFT_RATE
    # Tilted 30 degrees about x (the dish's rim still on the table): open and start over.
    angle = np.radians(30)
    tilted = replace(s.bodies[PAN], quat=np.array([np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0]))
    drooping = replace(held, bodies={**s.bodies, PAN: tilted})
    assert pan.tilt(tilted) == pytest.approx(angle)
    assert skills.pick(drooping, PAN, skills.Knobs()).action[6] == skills.OPEN
