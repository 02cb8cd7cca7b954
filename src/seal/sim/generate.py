"""Create the derived suites' data: new BDDL problems (text) and init states (simulator).

BDDL problems are built from LIBERO-10's by the text builders of ``seal.sim.variants``.
Init states are drawn the way LIBERO drew its own: the problem's placement sampler puts every
object in its init region (``env.reset()``), and the flattened MuJoCo state is kept. Each draw
is seeded (LIBERO's samplers use NumPy's global generator, which we seed and restore around
the draw), so a stored state can be re-drawn bit for bit from its seed. A draw is kept only
if the scene is at rest and sane after the settle steps (`seal.sim.start_check`).

Stored file: ``seal/data/init_states/<suite>/<problem>.npz`` with ``states`` (n, 1+nq+nv),
``seeds`` (n,) and ``bddl_sha256`` of the problem file the states belong to.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seal.errors import InvalidInput, SimulationError
from seal.sim.start_check import check_state
from seal.sim.suites import (
    DERIVED_SUITES,
    TaskSpec,
    get_task,
    instructions,
    libero_task,
    shipped_bddl_path,
    task_count,
)
from seal.sim.variants import COMPOSITION, VISUAL_SCENE, ProVariant, Replace, compose, replace_object

N_INIT_STATES = 50
MAX_DRAWS = 400  # give up on a task if this many draws do not yield the states asked for


# ---- BDDL ------------------------------------------------------------------------------------
def bddl_texts(suite: str) -> dict[Path, str]:
    """The BDDL problems a derived suite ships, path -> text (empty for suites that ship none)."""
    out: dict[Path, str] = {}
    if suite == "visual_scene":
        for task_id, edit in VISUAL_SCENE.items():
            if isinstance(edit, Replace):
                base = libero_task("libero_10", task_id)
                out[shipped_bddl_path(suite, base.name)] = replace_object(base.bddl_path.read_text(), edit)
    elif suite == "composition":
        for task_id, task in enumerate(COMPOSITION):
            base = libero_task("libero_10", task.base_task)
            spec = get_task(suite, task_id)
            out[spec.bddl_path] = compose(base.bddl_path.read_text(), task, instructions()[(suite, task_id)])
    return out


def write_bddl(suite: str) -> list[Path]:
    """Write the suite's BDDL problems; returns the files whose content changed."""
    changed = []
    for path, text in bddl_texts(suite).items():
        if not path.is_file() or path.read_text() != text:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
            changed.append(path)
    return changed


def needs_generated_states(spec: TaskSpec) -> bool:
    """Whether the task's init states are ours to generate (a new or changed object set)."""
    if spec.suite == "composition":
        return True
    if spec.suite == "visual_scene":
        edit = VISUAL_SCENE[spec.task_id]
        return not (isinstance(edit, ProVariant) and edit.shipped_init_states)
    return False


def generated_tasks(suite: str) -> list[TaskSpec]:
    if suite not in DERIVED_SUITES:
        raise InvalidInput(f"suite {suite!r} has no generated data; suites that may: {', '.join(DERIVED_SUITES)}")
    return [s for s in (get_task(suite, i) for i in range(task_count(suite))) if needs_generated_states(s)]


# ---- init states -----------------------------------------------------------------------------
def task_seed(spec: TaskSpec) -> int:
    """First draw seed of a task: stable across runs and machines, distinct per task."""
    return zlib.crc32(spec.key.encode()) * 1000


@dataclass
class Generated:
    states: np.ndarray
    seeds: np.ndarray
    rejected: dict[int, str] = field(default_factory=dict)  # seed -> reason


def generate_init_states(spec: TaskSpec, n: int = N_INIT_STATES, *, world=None, progress=None) -> Generated:
    """Draw seeds from `task_seed` upwards until ``n`` usable states are found."""
    from seal.sim.world import LiberoWorld

    own = world is None
    world = LiberoWorld(spec) if own else world
    try:
        states, seeds, rejected = [], [], {}
        seed = task_seed(spec)
        while len(states) < n:
            if len(states) + len(rejected) >= MAX_DRAWS:
                raise SimulationError(f"{spec.key}: only {len(states)} usable init states in {MAX_DRAWS} draws; "
                                      f"last rejection: {list(rejected.values())[-1]}")
            state = world.draw_state(seed)
            reason = "no collision-free placement" if state is None else check_state(world, state)
            if reason:
                rejected[seed] = reason
            else:
                states.append(state)
                seeds.append(seed)
                if progress is not None:
                    progress(len(states), n)
            seed += 1
        return Generated(np.stack(states), np.array(seeds, dtype=np.int64), rejected)
    finally:
        if own:
            world.close()


def bddl_digest(spec: TaskSpec) -> str:
    return hashlib.sha256(spec.bddl_path.read_bytes()).hexdigest()


def save_init_states(spec: TaskSpec, generated: Generated) -> Path:
    path = spec.init_states_path
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz")  # write aside, then rename: never half a file
    with os.fdopen(fd, "wb") as f:
        np.savez_compressed(f, states=generated.states, seeds=generated.seeds, bddl_sha256=np.array(bddl_digest(spec)))
    os.chmod(tmp, 0o644)  # package data: mkstemp's owner-only mode would hide it from other users
    os.replace(tmp, path)
    return path


def stored_seeds(spec: TaskSpec) -> tuple[np.ndarray, str]:
    """The seeds and BDDL digest stored with a task's generated init states."""
    with np.load(spec.init_states_path, allow_pickle=False) as f:
        return f["seeds"], str(f["bddl_sha256"])


def is_current(spec: TaskSpec) -> bool:
    """Stored init states exist and belong to the task's current BDDL file."""
    if not spec.init_states_path.is_file():
        return False
    return stored_seeds(spec)[1] == bddl_digest(spec)


def generate_suite(suite: str, tasks: list[int] | None = None, *, n: int = N_INIT_STATES, force: bool = False,
                   progress=None) -> dict[str, str]:
    """Write the suite's BDDL problems, then the init states of every task that needs generated
    ones and lacks current ones (or all, with ``force``). Each task's file is written when done,
    so an interrupted run resumes where it stopped. Returns task key -> what happened."""
    specs = generated_tasks(suite)
    if tasks is not None:
        for t in tasks:
            get_task(suite, t)  # validates the id
        specs = [s for s in specs if s.task_id in tasks]
    write_bddl(suite)
    out: dict[str, str] = {}
    for spec in specs:
        if not force and is_current(spec):
            out[spec.key] = "kept"
            continue
        if progress is not None:
            progress(spec, 0, n)
        g = generate_init_states(spec, n, progress=(lambda i, total, s=spec: progress(s, i, total)) if progress else None)
        save_init_states(spec, g)
        out[spec.key] = f"generated {len(g.states)} (rejected {len(g.rejected)} draws)"
    return out
