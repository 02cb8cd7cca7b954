"""Tall objects (bottles, cartons): grip width at the cap, laying a bottle down in a drawer,
and slots in a basket shared with a carton. Geometry is read from real LIBERO worlds."""


import numpy as np
import pytest
from _worlds import world_at
from openpi_client import msgpack_numpy

from seal.episode import run_policy_episode
from seal.policies.expert import lay, skills
from seal.policies.expert.motion import horizontal_frame
from seal.policies.expert.policy import FailureKnobs, ScriptedExpert
from seal.serving import protocol as P
from seal.sim.world import LiberoWorld

KETCHUP, DRAWER = "ketchup_1", "white_cabinet_1_top_region"


@pytest.fixture(scope="module")
def drawer_world():
    with world_at("libero_90", 32) as w:  # put the ketchup in the top drawer of the cabinet
        yield w


def test_ketchup_is_gripped_at_its_cap_not_its_body(drawer_world):
    s = drawer_world.scene_state()
    body = s.bodies[KETCHUP]
    assert len(body.parts) > 3  # the bottle's collision boxes, one by one
    yaw0, ext = horizontal_frame(body)
    # Its own frame stands along local y: the horizontal sides are ~3.4 and ~5.6 cm, not the height.
    assert np.all(ext < 0.07) and body.size[2] > 0.13
    assert skills.is_tall(body)
    point, yaw = skills.grasp_pose(s, KETCHUP, skills.Knobs())
    across = skills._grip_width(KETCHUP, body, yaw, point[2])
    # Across the narrow side, at the height the pads close (the cap, ~3.8 cm).
    assert 0.03 < across < 0.045
    assert across < float(np.max(ext)) - 0.01


def test_a_bottle_lies_down_in_a_drawer_but_not_a_bowl(drawer_world):
    s = drawer_world.scene_state()
    d = lay.laying_direction(s, KETCHUP, DRAWER)
    assert d is not None and d @ np.array([1.0, 0.0, 0.0]) > 0.99  # along the drawer, away from the robot
    assert lay.laying_direction(s, "akita_black_bowl_1", DRAWER) is None  # short: stands
    assert lay.laying_direction(s, KETCHUP, "white_cabinet_1_top_side") is None  # not a drawer


def test_parts_survive_the_wire(drawer_world):
    s = drawer_world.scene_state()
    back = P.scene_from_wire(msgpack_numpy.unpackb(msgpack_numpy.packb(P.scene_to_wire(s))))
    a, b = s.bodies[KETCHUP], back.bodies[KETCHUP]
    assert len(a.parts) == len(b.parts)
    assert np.allclose([p.center for p in a.parts], [p.center for p in b.parts])
    assert back.bodies["white_cabinet_1"].parts == ()  # fixtures carry none


def test_basket_slots_keep_a_carton_clear_of_the_walls():
    w = LiberoWorld(("composition", 2))  # the orange juice and the tomato sauce in the basket
    try:
        w.reset(0)
        s = w.scene_state()
        target = "basket_1_contain_region"
        site = s.sites[target]
        half = (np.abs(site.xmat) @ site.size)[:2]
        axis = skills._slot_axis(s, target)
        first = skills.slot_point(s, "orange_juice_1", target, (0, 2))
        second = skills.slot_point(s, "tomato_sauce_1", target, (1, 2))
        carton = float(skills._footprint(s.bodies["orange_juice_1"])[0])
        can = float(skills._footprint(s.bodies["tomato_sauce_1"])[0])
        assert carton < 0.07  # its horizontal side, not its height
        # Side by side, each wholly inside the region.
        assert abs(first[axis] - second[axis]) >= (carton + can) / 2
        assert abs(first[axis] - site.pos[axis]) + carton / 2 <= half[axis] + 1e-6
        assert abs(second[axis] - site.pos[axis]) + can / 2 <= half[axis] + 1e-6
    finally:
        w.close()


@pytest.mark.slow
def test_expert_lays_the_ketchup_in_the_drawer(drawer_world):
    policy = ScriptedExpert.for_world(drawer_world, FailureKnobs.named("clean"))
    result = run_policy_episode(drawer_world, policy, init_index=0)
    assert result.success
