"""Geometry behind putting a mug into the microwave and two moka pots on one stove, read from
real LIBERO worlds (LIBERO-10 tasks 9 and 8), and the expert solving task 9 end to end."""

import numpy as np
import pytest
from _worlds import world_at

from seal.episode import run_policy_episode
from seal.policies.expert import skills, stow
from seal.policies.expert.articulated import opening, protrusion
from seal.policies.expert.policy import ScriptedExpert
from seal.sim.world import LiberoWorld

MUG, REGION = "white_yellow_mug_1", "microwave_1_heating_region"


@pytest.fixture(scope="module")
def microwave_world():
    with world_at("libero_10", 9) as w:
        yield w


def test_doorway_is_read_from_the_door(microwave_world):
    s = microwave_world.scene_state()
    o = opening(s, REGION)
    assert o is not None
    # The microwave opens toward the robot's right (-y): the closed door's outward normal.
    assert o.out @ np.array([0.0, -1.0, 0.0]) > 0.99
    assert o.depth(s.sites[REGION].pos) > 0.05  # the heating region lies behind the door
    assert o.depth(s.bodies[MUG].pos) < -0.2  # the mug starts out on the table in front
    assert 0 < o.lateral(s.sites[REGION].pos) < o.leaf
    assert protrusion(o, s.bodies[MUG]) > 0.2
    assert stow.stowing(s, MUG, REGION) is not None
    assert stow.stowing(s, MUG, "microwave_1_top_side") is None  # on top: no doorway to go through
    # A stove's knob is a vertical hinge too, but no doorway.
    stove = LiberoWorld(("libero_10", 8))
    try:
        stove.reset(0)
        assert opening(stove.scene_state(), "flat_stove_1_cook_region") is None
    finally:
        stove.close()


def test_mug_handle_grasp_is_across_the_handle(microwave_world):
    s = microwave_world.scene_state()
    body = s.bodies[MUG]
    direction, reach = skills.handle(MUG, body)
    # The handle points -y (toward the doorway's outside) and reaches ~8.7 cm from the cup axis.
    assert direction @ np.array([0.0, -1.0]) > 0.99
    assert 0.075 < reach < 0.095
    point, yaw = skills.handle_grasp(s, MUG)
    assert abs(np.cos(yaw)) > 0.99  # finger axis along x: across the handle
    assert point[1] < body.pos[1] - 0.05  # out on the handle, not over the cup
    assert body.lo[2] < point[2] < body.hi[2]
    assert skills.handle("akita_black_bowl_1", body) is None  # no handle, no handle grasp


def test_two_pots_get_separate_slots_on_the_stove():
    world = LiberoWorld(("libero_10", 8))
    try:
        world.reset(0)
        s = world.scene_state()
        region = "flat_stove_1_cook_region"
        a = skills.slot_point(s, "moka_pot_1", region, (0, 2))
        b = skills.slot_point(s, "moka_pot_2", region, (1, 2))
        pot = s.bodies["moka_pot_1"]
        narrow = float(np.min(pot.local_hi[:2] - pot.local_lo[:2]))
        assert np.linalg.norm(a - b) > narrow + 0.02  # side by side, not stacked
        site = s.sites[region]
        for p in (a, b):
            assert np.all(np.abs(p - site.pos[:2]) < site.size[:2])  # LIBERO's On tests origins
        assert a[0] > b[0]  # the first one farther from the robot
    finally:
        world.close()


@pytest.mark.slow
def test_expert_puts_the_mug_in_the_microwave_and_closes_it(microwave_world):
    policy = ScriptedExpert.for_world(microwave_world)
    result = run_policy_episode(microwave_world, policy, init_index=0)
    assert result.success and not result.sim_error, result.goal_status
