"""Standing a thin upright object (a book) into a compartment (a desk caddy's slot).

`skills.place` lets go of things just above a container's rim. A standing book is 13 cm tall
and 3 cm thin: dropped from the rim of a caddy it topples, lands across the walls, and
cannot be picked up again (lying flat it is too wide for the open hand). A narrow slot
(the caddy's front compartment is 5.7 cm wide) also only takes the book with its wide side
along the slot. So this place:

* turns the held book so its wide side runs along the compartment's longer side (or, for a
  square compartment, whichever way needs the smaller wrist turn);
* centres the book's box (not its origin, which sits off-centre on its bottom edge) over the
  compartment, within the slack its walls leave;
* lowers it straight down, as deep as the hand allows: the hand, wider than the compartment,
  stays just above the holder's top while the book's lower part is already inside, then lets
  go; the walls guide the short fall to the floor.

Reactive like the other skills: every action is a function of the current state alone.
"""

from __future__ import annotations

import numpy as np

from seal.policies.expert.motion import finger_yaw, holder_of, path_top, wrap, yaw_error
from seal.policies.expert.skills import (CLOSE, HAND_ABOVE, OPEN, YAW_TOL, Z_TOL, Knobs, Step, carry, hold,
                                         in_hand, let_go_and_rise, move)
from seal.sim.scene import Body, SceneState

SLAB_THIN = 0.4  # thickness / width below this: a slab (a book), not a box
HAND_CLEARANCE = 0.012  # the hand's underside this far above the holder's top when letting go
FLOOR_CLEARANCE = 0.015  # never lower the book's bottom closer than this to the region's floor
WALL_MARGIN = 0.004  # keep the book's sides this far off the compartment's walls
ABOVE_WALLS = 0.03  # the book's bottom this far above the holder while lining up
MIN_TOL = 0.003  # release tolerance (each of x, y) never below this


def is_standing_slab(body: Body) -> bool:
    """An object standing on a narrow edge: thin one way, taller than it is wide, upright."""
    ext = body.local_hi - body.local_lo
    thick, wide = sorted(ext[:2])
    w, x, y, z = body.quat
    up = 1 - 2 * (x * x + y * y)  # z component of the body's own z axis
    return thick < SLAB_THIN * wide and ext[2] >= wide and up > 0.9


def standing_in(s: SceneState, obj: str, target: str | None) -> bool:
    """Whether ``obj`` is a standing slab going into a compartment of a holder (caddy, basket)."""
    if target is None or obj not in s.bodies or target not in s.sites or not target.endswith("contain_region"):
        return False
    if holder_of(s, target) is None:
        return False
    return is_standing_slab(s.bodies[obj])


def _wide_yaw(body: Body) -> float:
    """World yaw of the body's wide horizontal side."""
    ext = body.local_hi - body.local_lo
    return body.yaw + (np.pi / 2 if ext[1] >= ext[0] else 0.0)


def _slack(body: Body, half: np.ndarray, angle: float) -> np.ndarray:
    """World (x, y) room the book's centre has inside the region box with its wide side at
    world yaw ``angle``: the region's half size less the turned book's half extent."""
    ext = body.local_hi - body.local_lo
    thick, wide = sorted(ext[:2])
    c, si = abs(np.cos(angle)), abs(np.sin(angle))
    reach = np.array([wide * c + thick * si, wide * si + thick * c]) / 2
    return half[:2] - reach - WALL_MARGIN


def _target(s: SceneState, body: Body, half: np.ndarray) -> tuple[float, np.ndarray]:
    """The finger yaw that gives the book the most room in the compartment, and that room.

    The wide side goes along the compartment's long side, or across a square one's diagonal
    (a 12 cm square takes an 11 cm book along a side with 7 mm to spare, along its
    diagonal with 1.8 cm); of equally good ways, the smaller wrist turn."""
    now = finger_yaw(s)
    wide = _wide_yaw(body)
    best = None
    for angle in (0.0, np.pi / 2, np.pi / 4, -np.pi / 4):
        room = _slack(body, half, angle)
        yaw = now + wrap(angle - wide)
        score = float(np.min(room)) - 0.002 * abs(yaw_error(s, yaw))
        if best is None or score > best[0]:
            best = (score, yaw, room)
    return best[1], np.clip(best[2], MIN_TOL, 0.02)


def place_standing(s: SceneState, obj: str, target: str, knobs: Knobs) -> Step:
    body = s.bodies[obj]
    if not in_hand(s, obj):
        return let_go_and_rise(s, body)
    site = s.sites[target]
    half = np.abs(site.xmat) @ site.size
    holder = s.bodies[holder_of(s, target)]
    yaw, tol = _target(s, body, half)
    yaw_err = yaw_error(s, yaw)

    below = s.eef_pos[2] - body.lo[2]  # how far the book hangs below the gripper centre
    floor = site.pos[2] - half[2]
    # As deep as the hand allows (its underside above the holder's walls), not onto the floor.
    release_z = max(holder.hi[2] + HAND_CLEARANCE - HAND_ABOVE, floor + FLOOR_CLEARANCE + below)
    release_z += knobs.release_early
    over_z = holder.hi[2] + ABOVE_WALLS + below  # the book's bottom above every wall
    off = site.pos[:2] - body.center[:2]  # move the book's box centre onto the compartment's
    goal_xy = s.eef_pos[:2] + off
    dist = float(np.linalg.norm(off))
    if dist > 0.04:  # far: rise over everything on the way, then travel
        reach = float(np.max(body.size[:2])) / 2 + 0.02
        carry_z = max(over_z, path_top(s, s.eef_pos[:2], goal_xy, obj, reach) + below + 0.04)
        if s.eef_pos[2] < carry_z - 0.03:
            return Step(move(s.eef_pos, np.array([*s.eef_pos[:2], carry_z]), CLOSE, yaw_err))
        return Step(carry(s.eef_pos, np.array([*goal_xy, carry_z]), yaw_err))
    inside = body.lo[2] < holder.hi[2]  # the book's bottom already between the walls
    lined_up = np.all(np.abs(off) <= (1.5 if inside else 1.0) * tol) and abs(yaw_err) < YAW_TOL
    if not lined_up:
        # Line up above the walls (rising if a wall is in the way), never dragging it sideways.
        z = max(s.eef_pos[2], over_z) if not inside or np.any(np.abs(off) > 2 * tol) else s.eef_pos[2]
        return Step(carry(s.eef_pos, np.array([*goal_xy, z]), yaw_err))
    if s.eef_pos[2] - release_z > Z_TOL:
        return Step(carry(s.eef_pos, np.array([*goal_xy, release_z]), yaw_err))
    return Step(hold(OPEN))
