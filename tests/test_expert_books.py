"""Books into a desk caddy's compartments and onto a two-layer shelf (LIBERO-90 tasks 73-89):
the geometry the expert reads from real worlds, and (slow) whole episodes."""

import numpy as np
import pytest
from _worlds import world_at

from seal.episode import run_policy_episode
from seal.policies.expert import shelf, upright
from seal.policies.expert.policy import FailureKnobs, ScriptedExpert
from seal.sim.world import LiberoWorld

BOOK = "black_book_1"
SHELF_TOP, SHELF_BOTTOM = "wooden_two_layer_shelf_1_top_region", "wooden_two_layer_shelf_1_bottom_region"


@pytest.fixture(scope="module")
def caddy_scene():
    with world_at("libero_90", 73) as w:
        yield w.scene_state()


@pytest.fixture(scope="module")
def shelf_scene():
    with world_at("libero_90", 86) as w:
        yield w.scene_state()


def _wide_angle_after(s, yaw):
    """World yaw of the book's wide side once the hand has turned to finger yaw ``yaw``."""
    turn = yaw - np.arctan2(s.finger_axis[1], s.finger_axis[0])
    return upright._wide_yaw(s.bodies[BOOK]) + turn


def test_a_standing_book_goes_into_caddy_compartments_only(caddy_scene):
    s = caddy_scene
    assert upright.is_standing_slab(s.bodies[BOOK])
    assert not upright.is_standing_slab(s.bodies["white_yellow_mug_1"])
    assert upright.standing_in(s, BOOK, "desk_caddy_1_front_contain_region")
    assert not upright.standing_in(s, BOOK, "study_table_desk_caddy_right_region")  # a table region
    assert not upright.standing_in(s, "white_yellow_mug_1", "desk_caddy_1_front_contain_region")


def test_book_lines_up_with_the_slot_and_across_a_square_compartment(caddy_scene):
    s = caddy_scene
    half = lambda r: np.abs(s.sites[r].xmat) @ s.sites[r].size  # noqa: E731
    # The front slot is 5.6 cm deep (x) and 12.4 cm long (y): the wide side must run along y.
    yaw, tol = upright._target(s, s.bodies[BOOK], half("desk_caddy_1_front_contain_region"))
    assert abs(np.sin(_wide_angle_after(s, yaw))) > 0.99
    assert 0.003 <= tol[1] < tol[0] < 0.02
    # The right compartment is square: the 11 cm book goes along a diagonal, with room to spare.
    yaw, tol = upright._target(s, s.bodies[BOOK], half("desk_caddy_1_right_contain_region"))
    assert abs(abs(np.cos(_wide_angle_after(s, yaw))) - np.sqrt(0.5)) < 0.01
    assert np.all(tol > 0.006)


def test_shelf_levels_are_read_from_the_fixture(shelf_scene):
    s = shelf_scene
    top = shelf.level(s, SHELF_TOP)
    assert top is not None
    assert top.inward @ np.array([0.0, 1.0, 0.0]) > 0.99  # open toward -y, entered along +y
    assert 0.95 < top.floor < 0.96 and 1.09 < top.ceiling < 1.10  # the middle board, the roof
    assert shelf.under_roof(s, BOOK, SHELF_TOP) is not None
    bottom = shelf.level(s, SHELF_BOTTOM)
    assert bottom is not None and 0.95 < bottom.ceiling < 0.96
    # Turned level, a book stands 10-11 cm tall: too tall for the 7 cm bottom level.
    assert shelf.under_roof(s, "yellow_book_1", SHELF_BOTTOM) is None
    assert shelf.level(s, "wooden_two_layer_shelf_1_top_side") is None  # on the roof: nothing above


@pytest.mark.slow
@pytest.mark.parametrize("task", [73, 80, 86, 88])
def test_expert_puts_the_book_away(task):
    world = LiberoWorld(("libero_90", task))
    try:
        policy = ScriptedExpert.for_world(world, FailureKnobs.named("clean"))
        assert run_policy_episode(world, policy, init_index=0).success
    finally:
        world.close()
