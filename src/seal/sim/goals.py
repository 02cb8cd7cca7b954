"""Goal atoms: the task goal split into facts that can each be checked on their own.

A LIBERO goal is a conjunction such as ``(And (In alphabet_soup_1 basket_1_contain_region)
(In tomato_sauce_1 basket_1_contain_region))``. Steering verifies sub-plans, and a sub-plan
usually concerns one conjunct ("place the soup in the basket") or an intermediate fact that is
not in the goal at all ("pick up the soup"), hence ``Grasped`` and ``Held``: robosuite's grasp check
wants both finger *pads* on the object, and a mug or a moka pot held up by its handle often rests on
a finger's body instead, so the pad check flickers while the object is plainly in the hand. ``Held``
counts either surface of each finger (docs/verifier.md, "What the oracle calls a grasp").
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from seal.errors import InvalidInput

# LIBERO's predicate keys (lower case, as its BDDL parser stores them) -> display names.
PREDICATES = {
    "in": "In",
    "on": "On",
    "open": "Open",
    "close": "Close",
    "turnon": "TurnOn",
    "turnoff": "TurnOff",
    "grasped": "Grasped",  # ours: both finger pads touch the object (robosuite's grasp check)
    "held": "Held",  # ours: each finger touches the object, with its pad or its body
}
ARTICULATION = ("open", "close", "turnon", "turnoff")  # states of a hinge or slide, not of a free object
ARITY = {"in": 2, "on": 2, "open": 1, "close": 1, "turnon": 1, "turnoff": 1, "grasped": 1, "held": 1}
_DISPLAY_TO_KEY = {v.lower(): k for k, v in PREDICATES.items()}
_ATOM_RE = re.compile(r"^\s*([A-Za-z_]+)\s*\(\s*([^()]*?)\s*\)\s*$")
# The two ways to call an object picked up, by name: "fingers" (Held) and "pads" (Grasped, what every
# result before 2026-12-05 ran with). The oracle's pick check and the scripted expert's grip both choose one.
GRASP_CHECKS = ("fingers", "pads")
_GRASP_PREDICATE = {"fingers": "Held", "pads": "Grasped"}


def hold_atom(obj: str, grasp: str = GRASP_CHECKS[0]) -> str:
    """The fact that says ``obj`` is in the hand under the pick check ``grasp``: ``Held(obj)`` or
    ``Grasped(obj)``."""
    if grasp not in _GRASP_PREDICATE:
        raise InvalidInput(f"unknown grasp check {grasp!r}; valid: {', '.join(GRASP_CHECKS)}")
    return f"{_GRASP_PREDICATE[grasp]}({obj})"


@dataclass(frozen=True)
class GoalAtom:
    """One checkable fact, e.g. ``In(alphabet_soup_1, basket_1_contain_region)``."""

    predicate: str  # a key of PREDICATES
    args: tuple[str, ...]

    def __post_init__(self) -> None:
        if self.predicate not in PREDICATES:
            raise InvalidInput(
                f"unknown predicate {self.predicate!r}; valid: {', '.join(PREDICATES.values())}"
            )
        if len(self.args) != ARITY[self.predicate]:
            raise InvalidInput(
                f"{PREDICATES[self.predicate]} takes {ARITY[self.predicate]} argument(s), got {len(self.args)}: {self.args}"
            )

    def __str__(self) -> str:
        return f"{PREDICATES[self.predicate]}({', '.join(self.args)})"

    @property
    def subject(self) -> str:
        """The object the fact is about (the first argument)."""
        return self.args[0]

    @classmethod
    def parse(cls, text: str) -> "GoalAtom":
        """Parse the display form, e.g. ``"On(moka_pot_1, flat_stove_1_cook_region)"``."""
        match = _ATOM_RE.match(text)
        if not match:
            raise InvalidInput(f"cannot parse goal atom {text!r}; expected e.g. 'In(obj_1, region_1)'")
        name, args = match.groups()
        key = _DISPLAY_TO_KEY.get(name.lower(), name.lower())
        return cls(key, tuple(a.strip() for a in args.split(",") if a.strip()))

    @classmethod
    def from_bddl(cls, state: list[str]) -> "GoalAtom":
        """From one entry of LIBERO's ``parsed_problem['goal_state']``, e.g. ``['in', 'a', 'b']``."""
        return cls(state[0].lower(), tuple(state[1:]))

    def to_bddl(self) -> list[str]:
        return [self.predicate, *self.args]
