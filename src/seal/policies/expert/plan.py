"""Task decomposition: a LIBERO goal -> an ordered list of sub-plans in plain language.

Each sub-plan names one skill and the fact that proves it done (its sub-goal):

    pick up X          Grasped(X)
    place it in/on T   In(X, T) / On(X, T)       (the task's own goal atom)
    open / close D     Open(D) / Close(D)
    turn on / off S    TurnOn(S) / TurnOff(S)

Order respects physical dependencies: a drawer is opened before something is put in it and
closed after; a container is moved before something is stacked on it; the stove is switched
on first when the instruction says so first, otherwise last.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from seal.errors import InvalidInput
from seal.sim.goals import PREDICATES as PREDICATE_NAMES, GoalAtom
from seal.sim.lexicon import NAMES, category

SKILLS = ("pick", "place", "open", "close", "turn_on", "turn_off")

PLATE_SIDES = {"plate_1": "left plate", "plate_2": "right plate"}
DRAWER_FIXTURES = ("white_cabinet", "wooden_cabinet")
_LEVELS = ("top", "middle", "bottom")


@dataclass(frozen=True)
class SubPlan:
    text: str  # e.g. "pick up the alphabet soup"
    skill: str  # one of SKILLS
    obj: str  # the LIBERO name acted on (object, drawer region, stove, microwave)
    goal: GoalAtom  # the sub-goal that proves this sub-plan done
    target: str | None = None  # place: the region or object it goes in/on


def object_phrase(name: str, instruction: str = "") -> str:
    # Two plates told apart by side: say which, even when the instruction only says
    # "the left one ... the right one".
    if name in PLATE_SIDES and (PLATE_SIDES[name] in instruction or ("left" in instruction and "right" in instruction)):
        return PLATE_SIDES[name]
    options = NAMES.get(category(name), (category(name).replace("_", " "),))
    for phrase in options:
        if phrase in instruction:
            return phrase
    return options[0]


def _fixture_of(region: str, fixtures: list[str]) -> str | None:
    for f in sorted(fixtures, key=len, reverse=True):
        if region.startswith(f + "_"):
            return f
    return None


def _is_drawer(region: str) -> bool:
    return any(region.startswith(f) for f in DRAWER_FIXTURES) and any(f"_{lv}_region" in region for lv in _LEVELS)


def _drawer_phrase(region: str) -> str:
    level = next(lv for lv in _LEVELS if f"_{lv}_region" in region)
    return f"the {level} drawer"


def target_phrase(predicate: str, target: str, names: list[str], instruction: str) -> str:
    """How to say where something goes, e.g. 'in the basket', 'to the right of the plate'."""
    if target in names and not target.endswith("_region") and not target.endswith("_side"):
        return f"on the {object_phrase(target, instruction)}"  # On(x, plate_1)
    # A table region named after a nearby object: living_room_table_plate_right_region.
    m = re.match(r"^\w+?_table_(\w+)_(left|right|front|back)_region$", target)
    if m:
        ref, side = m.groups()
        ref_phrase = next((p for c, ps in NAMES.items() if c == ref for p in ps), ref.replace("_", " "))
        return f"to the {side} of the {ref_phrase}"
    fixture = _fixture_of(target, names)
    if fixture is not None:
        rest = target[len(fixture) + 1 :]
        thing = object_phrase(fixture, instruction)
        if _is_drawer(target):
            return f"in {_drawer_phrase(target)}"
        if rest == "top_side":
            return f"on top of the {thing}"
        if rest == "contain_region":
            return f"in the {thing}"
        if rest.endswith("_contain_region"):  # desk_caddy_1_back_contain_region
            return f"in the {rest[: -len('_contain_region')]} compartment of the {thing}"
        if rest == "cook_region":
            return f"on the {thing}"
        if rest == "heating_region":
            return f"in the {thing}"
        if rest == "top_region":
            return f"on the {thing}" if predicate == "in" else f"on top of the {thing}"
        if rest == "bottom_region":
            return f"under the {thing}"
        return f"{'in' if predicate == 'in' else 'on'} the {thing}"
    return f"{'in' if predicate == 'in' else 'on'} the {target.replace('_', ' ')}"


def decompose(goal_atoms: list[GoalAtom], instruction: str, names: list[str], *, task: str = "",
              initially_open: tuple[str, ...] = ()) -> list[SubPlan]:
    """Ordered sub-plans for a task goal.

    ``names`` are the scene's objects, fixtures and regions (to resolve what a region belongs to);
    ``initially_open`` lists drawers the task's initial state opens (BDDL ``:init``).
    """
    instruction = instruction.lower().rstrip(".")
    for atom in goal_atoms:
        if atom.predicate not in ("in", "on", "open", "close", "turnon", "turnoff"):
            raise InvalidInput(f"unsupported predicate {PREDICATE_NAMES.get(atom.predicate, atom.predicate)} ({atom}) in task {task or repr(instruction)}; supported: In, On, Open, Close, TurnOn, TurnOff")
    placements = [a for a in goal_atoms if a.predicate in ("in", "on")]
    goal_opens = {a.subject for a in goal_atoms if a.predicate == "open"}
    needs_open = [a.args[1] for a in placements if _is_drawer(a.args[1])
                  and a.args[1] not in initially_open and a.args[1] not in goal_opens]
    switch_first = bool(re.search(r"turn (on|off)|switch", instruction)) and (
        re.search(r"turn (on|off)|switch", instruction).start()
        < min((m.start() for m in re.finditer(r"\b(put|place|pick|move|set)\b", instruction)), default=10**6))

    def rank(atom: GoalAtom) -> tuple[int, int]:
        if atom.predicate == "open":
            return (0, 0) if any(p.args[1] == atom.subject for p in placements) else (1, 0)
        if atom.predicate in ("turnon", "turnoff"):
            return (0, 0) if switch_first else (3, 0)
        if atom.predicate == "close":
            filled = any(p.args[1] == atom.subject or p.args[1].startswith(atom.subject + "_") for p in placements)
            return (2, 0) if filled else (1, 0)
        # A placement whose target object is itself moved by another placement waits for it.
        waits = any(p.subject == atom.args[1] for p in placements if p is not atom)
        return (1, 1 if waits else 0)

    ordered = sorted(goal_atoms, key=rank)  # stable: goal order within a rank
    plans: list[SubPlan] = []
    for region in needs_open:
        plans.append(SubPlan(f"open {_drawer_phrase(region)}", "open", region, GoalAtom("open", (region,))))
    subjects = [a.subject for a in placements]
    for atom in ordered:
        if atom.predicate in ("in", "on"):
            obj, target = atom.args
            phrase = object_phrase(obj, instruction)
            same = [s for s in subjects if object_phrase(s, instruction) == phrase]
            if len(same) > 1:  # two moka pots: say which one
                phrase = f"{('first', 'second', 'third')[same.index(obj)]} {phrase}"
            where = target_phrase(atom.predicate, target, names, instruction)
            if target in names and category(target) == category(obj):
                where = f"on the other {object_phrase(target, instruction)}"
            plans.append(SubPlan(f"pick up the {phrase}", "pick", obj, GoalAtom("grasped", (obj,))))
            plans.append(SubPlan(f"place it {where}", "place", obj, atom, target=target))
        else:
            subject = atom.subject
            if _is_drawer(subject):
                thing = _drawer_phrase(subject)
            else:
                thing = f"the {object_phrase(subject, instruction)}"
            verb = {"open": "open", "close": "close", "turnon": "turn on", "turnoff": "turn off"}[atom.predicate]
            skill = {"open": "open", "close": "close", "turnon": "turn_on", "turnoff": "turn_off"}[atom.predicate]
            plans.append(SubPlan(f"{verb} {thing}", skill, subject, atom))
    return plans


def bddl_names(bddl_text: str) -> list[str]:
    """Object and fixture instance names declared in a BDDL problem (``name - type`` lines)."""
    names = []
    for section in ("fixtures", "objects"):
        m = re.search(rf"\(:{section}(.*?)\)", bddl_text, flags=re.S)
        if m:
            for line in m.group(1).splitlines():  # "plate_1 plate_2 - plate"
                if " - " in line:
                    names += line.split(" - ")[0].split()
    return sorted(names)


def plan_task(spec) -> list[SubPlan]:
    """Sub-plans for a `TaskSpec` from its BDDL file alone (no simulator needed)."""
    text = spec.bddl_path.read_text()
    return decompose(spec.goal_atoms(), spec.instruction, bddl_names(text), task=spec.key,
                     initially_open=spec.initially_open())
