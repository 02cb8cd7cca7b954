"""Whether a flattened MuJoCo state is a usable start of its task (`check_state`).

Init-state generation (`seal.sim.generate`), fresh starts for recordings (`LiberoWorld.reset_sampled`)
and verification-case collection all keep a drawn state only if it passes. The check drives a
`seal.sim.world.LiberoWorld` through its public calls only (reset_to_state, settle, object
positions, goal atoms), so this module imports nothing of the world's.
"""

from __future__ import annotations

import re

import numpy as np

from seal.errors import SimulationError
from seal.sim.suites import TaskSpec

# No-op steps after the settle steps; the second half must be still. LIBERO's own starts are not
# all at rest after the settle steps: in the LIVING_ROOM_SCENE2 tasks the ketchup spawns
# overlapping the table and is thrown ~60 cm up, landing ~0.6 s later - for every init state,
# official or ours, since the spawn height is LIBERO's. We accept that, as LIBERO-10 does.
REST_STEPS = 40
MAX_SLIDE = 0.02  # metres an object may move sideways while settling
MAX_DROP = 0.10  # metres an object may sink while settling (LIBERO spawns some up to ~7 cm above the table)
MAX_MOTION = 0.005  # metres an object may still move during the rest steps


def check_state(world, state: np.ndarray) -> str:
    """'' if ``state`` is a usable start, else why not.

    Usable: the physics stays stable; from the spawn pose to the end of the settle steps and
    `REST_STEPS` more, no object slid more than `MAX_SLIDE` or sank more than `MAX_DROP`
    (nothing toppled off, fell off or was pushed out of an overlap; LIBERO spawns some objects
    a few cm above the table, so a short drop is normal), and nothing still moves during the
    second half of the rest steps; the BDDL's unary init facts hold (a drawer left open, a stove on); and the task
    is not already done.
    """
    try:
        world.reset_to_state(state, settle=False)
        names = world.scene_objects
        spawn = np.array([world.object_position(n) for n in names])
        world.reset_to_state(state, settle=True)
        world.settle(REST_STEPS // 2)
        settled = np.array([world.object_position(n) for n in names])
        world.settle(REST_STEPS - REST_STEPS // 2)
    except SimulationError as exc:
        return f"unstable: {exc}"
    unplaced = [n for n, p in zip(names, spawn) if np.linalg.norm(p) < 1e-6]
    if unplaced:  # LIBERO leaves an object at the origin when its init region does not exist
        return f"not placed by the sampler: {', '.join(unplaced)}"
    rest = np.array([world.object_position(n) for n in names])
    slide = np.linalg.norm(rest[:, :2] - spawn[:, :2], axis=1)
    drop = spawn[:, 2] - rest[:, 2]
    moving = np.linalg.norm(rest - settled, axis=1)
    for n, s, d, m in zip(names, slide, drop, moving):
        if s > MAX_SLIDE:
            return f"{n} slid {s * 100:.1f} cm while settling"
        if d > MAX_DROP:
            return f"{n} sank {d * 100:.1f} cm while settling"
        if m > MAX_MOTION:
            return f"{n} still moves after the settle steps ({m * 1000:.0f} mm)"
    for atom in _unary_init_facts(world.task):
        if not world.check(atom):
            return f"init fact {atom} does not hold"
    if world.success():
        return "task already done"
    return ""


def _unary_init_facts(spec: TaskSpec) -> list[str]:
    text = spec.bddl_path.read_text()
    init = text[text.index("(:init") : text.index("(:goal")]
    return [f"{p}({a})" for p, a in re.findall(r"\((Open|Close|Turnon|Turnoff)\s+(\w+)\)", init, flags=re.I)]
