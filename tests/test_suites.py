"""The evaluation suites: every task resolves to files that exist and parse, its init states fit,
one task per suite builds a world whose first frame renders, generated init states are stored
and re-drawn bit for bit from their seeds. `-m slow` checks every task of every derived suite."""

import re

import numpy as np
import pytest

from seal.errors import InvalidInput
from seal.policies.expert.plan import plan_task
from seal.sim.generate import bddl_texts, is_current, needs_generated_states, stored_seeds
from seal.sim.start_check import check_state
from seal.sim.suites import DERIVED_SUITES, SUITES, get_task, instructions, list_tasks, task_count
from seal.sim.variants import COMPOSITION, VISUAL_SCENE, Replace
from seal.sim.world import LiberoWorld

EVAL_SUITES = ("libero_10",) + DERIVED_SUITES


def test_suite_names_counts_and_unique_keys():
    assert SUITES == ("libero_10", "libero_90", "lang_rephrase", "lang_object_property", "visual_scene",
                      "visual_viewpoint", "composition")
    counts = {s: task_count(s) for s in EVAL_SUITES}
    assert counts == {"libero_10": 10, "lang_rephrase": 10, "lang_object_property": 10, "visual_scene": 10,
                      "visual_viewpoint": 10, "composition": 13}
    keys = [t.key for s in EVAL_SUITES for t in list_tasks(s)]
    assert len(keys) == len(set(keys)) == 63
    assert get_task("visual_viewpoint", 3).key == "visual_viewpoint/3"


def test_unknown_suite_and_task_name_what_is_valid():
    with pytest.raises(InvalidInput, match="unknown suite 'lang_rephrased'; valid suites: libero_10, libero_90, "
                                           "lang_rephrase, lang_object_property, visual_scene, visual_viewpoint, composition"):
        get_task("lang_rephrased", 0)
    with pytest.raises(InvalidInput, match=r"unknown task id 13 for suite 'composition'; valid ids: 0\.\.12"):
        get_task("composition", 13)
    with pytest.raises(InvalidInput, match="valid ids: 0..9"):
        get_task("visual_scene", -1)
    with pytest.raises(InvalidInput, match="valid ids"):
        get_task("lang_rephrase", "3")


def test_instructions_come_from_the_paper_tables():
    table = instructions()
    for suite in ("lang_rephrase", "lang_object_property", "composition"):
        for spec in list_tasks(suite):
            assert spec.instruction == table[(suite, spec.task_id)]
    for suite in ("visual_scene", "visual_viewpoint"):  # visual shifts keep LIBERO-10's words
        for spec in list_tasks(suite):
            assert spec.instruction == get_task("libero_10", spec.task_id).instruction
    lr = get_task("lang_object_property", 9)
    base = get_task("libero_10", 9)
    assert lr.bddl_path == base.bddl_path and lr.init_states_path == base.init_states_path
    assert lr.base_key == "libero_10/9" and lr.instruction == "put the middle mug inside the microwave and close the door"


def test_every_task_has_parsing_bddl_and_a_plan():
    from libero.libero.envs.bddl_utils import robosuite_parse_problem

    for suite in EVAL_SUITES:
        for spec in list_tasks(suite):
            problem = robosuite_parse_problem(str(spec.bddl_path))
            declared = {n for names in problem["objects"].values() for n in names}
            declared |= {n for names in problem["fixtures"].values() for n in names}
            for atom in problem["goal_state"]:
                for arg in atom[1:]:
                    assert arg in declared or arg.endswith("_region"), (spec.key, arg)
            for atom in problem["initial_state"]:  # every placement names a region that exists
                if atom[0].lower() == "on" and atom[2].endswith("_init_region"):
                    assert atom[1] in declared and atom[2] in problem["regions"], (spec.key, atom)
            plans = plan_task(spec)  # the scripted expert can decompose it
            assert plans and all(p.text for p in plans), spec.key
            assert spec.change or suite == "libero_10", spec.key


def test_shipped_bddl_files_are_the_builders_output():
    for suite in ("visual_scene", "composition"):
        texts = bddl_texts(suite)
        assert texts, suite
        for path, text in texts.items():
            assert path.is_file() and path.read_text() == text, f"{path} is stale: run `seal suites generate {suite}`"


def test_visual_scene_edits_change_only_a_non_target_object():
    for task_id, edit in VISUAL_SCENE.items():
        spec, base = get_task("visual_scene", task_id), get_task("libero_10", task_id)
        goal = spec.bddl_path.read_text().split("(:goal")[1]
        assert goal == base.bddl_path.read_text().split("(:goal")[1], spec.key  # same goal, same targets
        text = spec.bddl_path.read_text()
        if isinstance(edit, Replace):
            assert not re.search(rf"\b{edit.old}_1\b", text) and re.search(rf"\b{edit.new}_1 - {edit.new}\b", text)
    with pytest.raises(InvalidInput, match="target"):
        from seal.sim.variants import replace_object

        replace_object(get_task("libero_10", 3).bddl_path.read_text(), Replace("akita_black_bowl", "white_bowl"))


def test_stored_init_states_fit_and_belong_to_their_bddl():
    for suite in ("visual_scene", "composition"):
        for spec in list_tasks(suite):
            states = spec.init_states()
            assert states.shape[0] == 50, spec.key
            if needs_generated_states(spec):
                assert is_current(spec), f"{spec.key}: init states stale, run `seal suites generate {suite}`"
                seeds, _ = stored_seeds(spec)
                assert len(set(seeds.tolist())) == 50
            # Same object count as the scene it derives from (a replacement keeps the count):
            base_id = COMPOSITION[spec.task_id].base_task if suite == "composition" else spec.task_id
            base_dim = get_task("libero_10", base_id).init_states().shape[1]
            added = 13 if not isinstance(VISUAL_SCENE.get(spec.task_id), Replace) and suite == "visual_scene" else 0
            assert states.shape[1] == base_dim + added, spec.key  # a free body adds 7 qpos + 6 qvel


@pytest.fixture(scope="module")
def composition_world():
    w = LiberoWorld(get_task("composition", 10))
    yield w
    w.close()


def test_composition_init_states_are_redrawn_bit_for_bit_from_their_seeds(composition_world):
    spec = composition_world.task
    states = spec.init_states()
    seeds, _ = stored_seeds(spec)
    for j in (0, 49):
        np.testing.assert_array_equal(composition_world.draw_state(int(seeds[j])), states[j])
    assert check_state(composition_world, states[0]) == ""
    # A draw leaves the world usable: the stored start still loads and renders the same.
    composition_world.reset(0)
    assert composition_world.observe().agent.std() > 10


def test_first_frame_renders_in_each_suite(world, composition_world):
    """One task per suite (libero_10/0 comes from the shared fixture)."""
    world.reset(0)
    base0 = world.observe().agent.astype(float)
    assert base0.std() > 10
    frames = {}
    for suite, task_id in (("lang_rephrase", 0), ("lang_object_property", 5), ("visual_scene", 3),
                           ("visual_viewpoint", 0)):
        w = LiberoWorld(get_task(suite, task_id))
        try:
            w.reset(0)
            obs = w.observe()
            assert obs.agent.shape == (224, 224, 3) and obs.agent.std() > 10, suite
            assert obs.prompt == w.task.instruction
            frames[suite] = obs.agent.astype(float)
            if suite == "visual_viewpoint":
                # The moved camera still sees every object where it starts (after the settle steps
                # LIBERO's ketchup is still in the air above this table; see docs/suites.md).
                w.reset(0, settle=False)
                assert w.objects_out_of_view() == {}
                assert w.task.camera is not None and w.task.background == "kitchen"
            if suite == "visual_scene":
                assert "ketchup_1" in w.objects and "wine_bottle_1" not in w.objects
        finally:
            w.close()
    composition_world.reset(0)
    assert composition_world.observe().agent.std() > 10
    np.testing.assert_array_equal(frames["lang_rephrase"], base0)  # same scene, same start
    assert np.abs(frames["visual_viewpoint"] - base0).mean() > 20  # another room, another angle


@pytest.mark.slow
@pytest.mark.parametrize("suite", DERIVED_SUITES)
def test_every_task_of_every_derived_suite_checks_out(suite):
    from seal.suite_tools import check_task

    rows = [check_task(spec, inits=5) for spec in list_tasks(suite)]
    assert [r["task"] for r in rows if not r["ok"]] == [], [r["problems"] for r in rows if not r["ok"]]


# Every composition task, init state 0, clean expert. The five expected failures once listed here
# (tall cartons in the basket, the ketchup grasp, the wine bottle in the drawer) all passed once the
# xfails were made strict (2026-12-01). Since episodes start as openpi's do (per-episode fixture
# placements and the reset pose's controller state, seal.sim.layout), task 9 fails again on init 0:
# the bottle lies in the drawer but the drawer does not close (inits 0-5: 4/6, failing 0 and 4,
# `seal bench expert --suite composition --tasks 9 --trials 6 --no-misaligned`). Strict: a fix
# makes this test fail until the mark goes.
COMPOSITION_XFAIL = {9: "clean expert: the drawer does not close over the laid wine bottle on init 0"}


@pytest.mark.slow
@pytest.mark.parametrize("task_id", [
    pytest.param(t, marks=pytest.mark.xfail(reason=COMPOSITION_XFAIL[t], strict=True)) if t in COMPOSITION_XFAIL else t
    for t in range(len(COMPOSITION))])
def test_clean_expert_solves_composition_task(task_id):
    from seal.episode import run_policy_episode
    from seal.policies.expert.policy import FailureKnobs, ScriptedExpert

    w = LiberoWorld(get_task("composition", task_id))
    try:
        result = run_policy_episode(w, ScriptedExpert.for_world(w, FailureKnobs.named("clean")), init_index=0)
    finally:
        w.close()
    assert result.success, result.goal_status


@pytest.mark.slow
def test_viewpoint_camera_and_background_in_fast_render_mode():
    """The fast render model gets the moved camera too; kitchen assets (a palette PNG) load."""
    spec = get_task("visual_viewpoint", 3)  # a kitchen task in the study, camera moved
    stock, fast = LiberoWorld(spec), LiberoWorld(spec, render_mode="fast")
    base = LiberoWorld(get_task("libero_10", 3), render_mode="fast")
    try:
        for w in (stock, fast, base):
            w.reset(0)
        a, b, c = (w.observe().agent.astype(float) for w in (stock, fast, base))
    finally:
        for w in (stock, fast, base):
            w.close()
    assert np.abs(a - b).mean() < np.abs(b - c).mean() / 2  # fast looks like stock, not like LIBERO-10
