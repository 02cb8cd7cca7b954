"""Oracle grounding on words that did not come from the expert or from the suite's own files.

`test_oracle.py`'s 108/108 grounds the expert's own sub-plan texts, built from the instructions in
seal/data/instructions.csv, with a lexicon written alongside that expert: it checks consistency,
not coverage. The phrasings below were written for this test from the task goals alone, as a
person would say them (synonyms, particles moved, other word orders, pronouns), before running the
grounder on them, and were not edited afterwards to make them pass. The measured rate is recorded
in docs/performance.md ("Oracle grounding on independent phrasings") with every miss; the
assertions pin it so a lexicon change that loses coverage fails here, and one that gains coverage
must update the floor and the doc.
"""

from __future__ import annotations

import dataclasses

from seal.policies.expert.plan import bddl_names, plan_task
from seal.sim.goals import GoalAtom
from seal.sim.suites import get_task
from seal.verify.oracle import ground

BASKET = "basket_1_contain_region"
COOK = "flat_stove_1_cook_region"

# (LIBERO-10 task, plan context or None, sub-plan text, the goal atom it means)
PHRASINGS = [
    (0, None, "grab the can of alphabet soup", "Grasped(alphabet_soup_1)"),
    (0, None, "lift the soup can off the table", "Grasped(alphabet_soup_1)"),
    (0, None, "drop the soup into the basket", f"In(alphabet_soup_1, {BASKET})"),
    (0, None, "put the can of tomato sauce inside the basket", f"In(tomato_sauce_1, {BASKET})"),
    (0, None, "take the tomato sauce", "Grasped(tomato_sauce_1)"),
    (0, None, "the tomato sauce goes in the basket", f"In(tomato_sauce_1, {BASKET})"),
    (0, None, "in the basket, place the alphabet soup", f"In(alphabet_soup_1, {BASKET})"),
    (1, None, "pick the cream cheese up", "Grasped(cream_cheese_1)"),
    (1, None, "grab the butter box", "Grasped(butter_1)"),
    (1, None, "put the butter in the basket", f"In(butter_1, {BASKET})"),
    (1, None, "stick the cheese in the basket", f"In(cream_cheese_1, {BASKET})"),
    (1, None, "get hold of the cream cheese", "Grasped(cream_cheese_1)"),
    (1, ("take the butter", "put it in the basket"), "put it in the basket", f"In(butter_1, {BASKET})"),
    (2, None, "switch the stove on", "TurnOn(flat_stove_1)"),
    (2, None, "turn the burner on", "TurnOn(flat_stove_1)"),
    (2, None, "light the stove", "TurnOn(flat_stove_1)"),
    (2, None, "put the moka pot onto the stove", f"On(moka_pot_1, {COOK})"),
    (2, None, "set the coffee pot down on the burner", f"On(moka_pot_1, {COOK})"),
    (2, None, "grab the espresso maker", "Grasped(moka_pot_1)"),
    (2, ("grab the moka pot", "set it on the burner"), "set it on the burner", f"On(moka_pot_1, {COOK})"),
    (3, None, "grab the dark bowl", "Grasped(akita_black_bowl_1)"),
    (3, None, "put the bowl into the bottom drawer", "In(akita_black_bowl_1, white_cabinet_1_bottom_region)"),
    (3, None, "shut the bottom drawer", "Close(white_cabinet_1_bottom_region)"),
    (3, None, "push the lowest drawer closed", "Close(white_cabinet_1_bottom_region)"),
    (3, None, "close the drawer at the bottom", "Close(white_cabinet_1_bottom_region)"),
    (4, None, "grab the plain white mug", "Grasped(porcelain_mug_1)"),
    (4, None, "put the white cup on the plate on the left", "On(porcelain_mug_1, plate_1)"),
    (4, None, "lift the yellow-and-white mug", "Grasped(white_yellow_mug_1)"),
    (4, None, "set the yellow mug on the right-hand plate", "On(white_yellow_mug_1, plate_2)"),
    (5, None, "take the black book", "Grasped(black_book_1)"),
    (5, None, "slide the book into the rear compartment of the caddy", "In(black_book_1, desk_caddy_1_back_contain_region)"),
    (5, None, "put the book in the caddy's back slot", "In(black_book_1, desk_caddy_1_back_contain_region)"),
    (6, None, "place the pudding on the right side of the plate",
     "On(chocolate_pudding_1, living_room_table_plate_right_region)"),
    (6, None, "grab the pudding cup", "Grasped(chocolate_pudding_1)"),
    (6, None, "set the mug on the plate", "On(porcelain_mug_1, plate_1)"),
    (8, None, "pick up the second coffee pot", "Grasped(moka_pot_2)"),
    (8, None, "put the first moka pot on the stove", f"On(moka_pot_1, {COOK})"),
    (8, None, "turn the stove on", "TurnOn(flat_stove_1)"),
    (9, None, "pick up the white and yellow mug", "Grasped(white_yellow_mug_1)"),
    (9, None, "put the mug inside the microwave", "In(white_yellow_mug_1, microwave_1_heating_region)"),
    (9, None, "shut the microwave door", "Close(microwave_1)"),
    (9, None, "close the microwave oven", "Close(microwave_1)"),
    (9, ("lift the yellow and white mug", "stick it in the microwave"), "stick it in the microwave",
     "In(white_yellow_mug_1, microwave_1_heating_region)"),
]

# Task instructions written for this test (not read from seal/data/instructions.csv), two per task.
INSTRUCTIONS = {
    0: ["put the soup can and the can of tomato sauce into the basket",
        "place the alphabet soup in the basket, then the tomato sauce"],
    1: ["move the cheese box and the butter into the basket", "put the butter and the cream cheese in the bin"],
    2: ["switch on the burner and set the coffee pot on top of it", "light the stove, then put the moka pot on it"],
    3: ["place the black bowl into the lowest drawer and shut it",
        "put the dark bowl in the cabinet's bottom drawer, then close the drawer"],
    4: ["white mug onto the left plate, yellow-and-white mug onto the right plate",
        "put the plain white cup on the plate on the left and the white mug with yellow on the right plate"],
    5: ["put the book into the rear section of the desk caddy", "grab the book and slide it into the back of the caddy"],
    6: ["set the white mug on the plate and place the pudding on the right of the plate",
        "put the chocolate pudding right of the plate and the white cup on the plate"],
    7: ["put the soup and the cheese box into the basket", "drop both the alphabet soup and the cream cheese in the basket"],
    8: ["place both coffee pots on the burner", "put the two moka pots on the stove"],
    9: ["put the white and yellow mug inside the microwave and shut the door",
        "place the yellow mug in the microwave, then close the microwave"],
}

# Measured 2026-12-01 (docs/performance.md). Floors, not targets: see the module docstring.
PHRASINGS_GROUNDED = 30  # of 43; 11 are an explicit unknown and these two are WRONG atoms:
KNOWN_WRONG = {
    # "yellow-and-white" (hyphenated) is not matched as the yellow-and-white mug; "white" alone wins
    "lift the yellow-and-white mug": "Grasped(porcelain_mug_1)",
    # "on the right side of the plate" is read as "on the plate"
    "place the pudding on the right side of the plate": "On(chocolate_pudding_1, plate_1)",
}
INSTRUCTION_SUBPLANS_GROUNDED = 72  # of 72; see the second test for why this says less than it seems


def _names(task_id: int) -> list[str]:
    spec = get_task("libero_10", task_id)
    names = bddl_names(spec.bddl_path.read_text())
    for p in plan_task(spec):
        names += list(p.goal.args)
    return sorted(set(names))


def _phrasing_results() -> list[tuple[str, str, str]]:
    """(text, expected, got) for every phrasing; got is the grounded atoms or the reason it failed."""
    out = []
    for task, plans, text, atom in PHRASINGS:
        plans = plans or ()
        index = plans.index(text) if text in plans else None
        g = ground(text, plans, _names(task), index)
        got = ", ".join(map(str, g.atoms)) if g.atoms else f"unknown ({g.reason})"
        out.append((text, str(GoalAtom.parse(atom)), got))
    return out


def _instruction_results() -> list[tuple[str, str, str, str]]:
    """(instruction, sub-plan text, expected atom, got) for every sub-plan the expert writes."""
    out = []
    for task, texts in INSTRUCTIONS.items():
        for instruction in texts:
            spec = dataclasses.replace(get_task("libero_10", task), instruction=instruction)
            plans = plan_task(spec)
            subplans = tuple(p.text for p in plans)
            for i, p in enumerate(plans):
                g = ground(p.text, subplans, _names(task), i)
                got = ", ".join(map(str, g.atoms)) if g.atoms else f"unknown ({g.reason})"
                out.append((instruction, p.text, str(p.goal), got))
    return out


def test_independent_phrasings_ground_at_the_measured_rate():
    results = _phrasing_results()
    misses = [r for r in results if r[1] != r[2]]
    # A miss should be an explicit unknown, not a confident wrong atom (the oracle would then check
    # the wrong thing). Two known wrong ones are recorded above and in the doc; a new one fails.
    wrong = {text: got for text, _, got in misses if not got.startswith("unknown")}
    assert wrong.items() <= KNOWN_WRONG.items(), wrong
    assert len(results) == len(PHRASINGS) == 43
    assert len(results) - len(misses) >= PHRASINGS_GROUNDED, "\n".join(f"{t!r}: want {w}, got {g}" for t, w, g in misses)


def test_independent_instructions_give_groundable_subplans_at_the_measured_rate():
    """Instructions the suite files do not contain, through the expert's planner, then the oracle.
    72/72, but the expert mostly rewrites object words into its own names ("coffee pot" -> "moka
    pot", "bin" -> "basket"), so this checks that planner and oracle agree on new instructions,
    not the lexicon's coverage of new words (the phrasing test above measures that)."""
    results = _instruction_results()
    assert len(results) == 72
    misses = [r for r in results if r[2] != r[3]]
    assert all(got.startswith("unknown") for *_, got in misses), misses
    assert len(results) - len(misses) >= INSTRUCTION_SUBPLANS_GROUNDED, \
        "\n".join(f"{i!r} -> {t!r}: want {w}, got {g}" for i, t, w, g in misses)
