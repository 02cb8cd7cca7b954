"""Putting an object into a fixture behind a hinged door (LIBERO's microwave).

`skills.place` lowers things from above, which a roofed fixture does not allow: the hand,
8 cm thick and 10 cm tall above the fingers, cannot follow the object under the roof. So the
object goes in sideways, through the doorway, held by its handle (`skills.handle_grasp`)
with the hand's long side along the doorway and the handle pointing out: the object enters
first and the hand stops in front of the door's plane. Let go just inside (LIBERO's In tests
the object's origin against the region box); `articulated.close_door` then pushes in what
still sticks out (the handle) before it closes the door.

All geometry comes from the scene: the doorway from the door's hinge and leaf
(`articulated.opening`), heights from the target region, reach from the held object's box.
Rules are reactive, like the other skills: the action is a function of the current state.
"""

from __future__ import annotations

import numpy as np

from seal.policies.expert.articulated import Opening, opening
from seal.policies.expert.motion import path_top, yaw_error
from seal.policies.expert.skills import (CLOSE, HAND_HALF, OPEN, YAW_TOL, Z_TOL, Knobs,
                                         Step, carry, hold, in_hand, let_go_and_rise, move)
from seal.sim.scene import SceneState

ENTRY_CLEARANCE = 0.03  # the object's bottom this far above the region's floor while going in
RELEASE_DROP = 0.02  # ... and this far above it when let go (the floor is not in the scene state)
INSIDE_MARGIN = 0.01  # the origin this far inside the region's front face when let go
STAGE_GAP = 0.03  # in front of the doorway: the whole object this far out of the door's plane
UPRIGHT_GAIN = 0.6  # rotation action per radian of the held object's tilt
MAX_HAND_TILT = 0.7  # radians the hand may lean off pointing down to keep it upright
HAND_MARGIN = 0.0  # how far the hand's front face may reach past the door's plane


def stowing(s: SceneState, obj: str, target: str) -> Opening | None:
    """The doorway to go through, if ``target`` is a region behind a hinged door."""
    if target not in s.sites or obj not in s.bodies:
        return None
    o = opening(s, target)
    centre = s.sites[target].pos
    # Behind the door and below its top edge (a region on the fixture's roof is not inside).
    if o is None or o.depth(centre) <= 0 or not o.bottom - 0.02 < centre[2] < o.top:
        return None
    return o


def place_inside(s: SceneState, obj: str, target: str, knobs: Knobs) -> Step:
    o = stowing(s, obj, target)
    body = s.bodies[obj]
    if not in_hand(s, obj):
        # Let go: open, then straight up (the hand is in front of the doorway) and done.
        return let_go_and_rise(s, body)
    site = s.sites[target]
    half = np.abs(site.xmat) @ site.size
    p = body.pos
    hang = p - s.eef_pos  # the object's origin relative to the hand
    hang_in = float(-hang @ o.out)  # how far the object reaches into the doorway ahead of the hand
    corners = np.array([[x, y] for x in (body.lo[0], body.hi[0]) for y in (body.lo[1], body.hi[1])]) - p[:2]
    ahead = float(np.max(corners @ -o.out[:2]))  # the object's far side, inward of its origin

    # Where the origin goes: centred across the doorway (the region and the door leaf overlap),
    # just inside the region's front face, but not so deep that the hand passes the door plane.
    region_lat = o.lateral(site.pos) + np.array([-1, 1]) * float(half @ np.abs(o.along))
    lat_lo, lat_hi = max(region_lat[0], 0.0), min(region_lat[1], o.leaf)
    lateral = (lat_lo + lat_hi) / 2 - o.lateral(body.center) + o.lateral(p)  # the box centred
    front = o.depth(site.pos) - float(half @ np.abs(o.out))  # depth of the region's front face
    hand_limit = hang_in - HAND_HALF[1] + HAND_MARGIN
    depth = min(front + INSIDE_MARGIN, max(hand_limit, front + 0.005))
    floor = site.pos[2] - half[2]
    below = p[2] - body.lo[2]
    z_in = floor + ENTRY_CLEARANCE + below
    z_release = floor + RELEASE_DROP + below + knobs.release_early
    stage = o.point(lateral, -(ahead + STAGE_GAP), z_in)
    goal = o.point(lateral, depth, z_in)

    # The hand's long side along the doorway (the finger axis across a handle that points out).
    yaw_err = yaw_error(s, float(np.arctan2(o.along[1], o.along[0])))

    def to(obj_goal: np.ndarray) -> np.ndarray:
        return s.eef_pos + (obj_goal - p)  # the hand's goal for an object goal

    def upright(action: np.ndarray) -> Step:
        # Held by its handle, a mug sags about the finger axis (the pads' small contact
        # cannot hold its weight's torque); the hand tilts the other way to keep it upright,
        # which also leans the hand's top away from the doorway.
        w, x, y, zq = body.quat
        z_axis = np.array([2 * (x * zq + w * y), 2 * (y * zq - w * x), 1 - 2 * (x * x + y * y)])
        fix = UPRIGHT_GAIN * np.cross(z_axis, [0.0, 0.0, 1.0])
        tilt = float(np.arccos(np.clip(-s.eef_xmat[2, 2], -1.0, 1.0)))
        if tilt > MAX_HAND_TILT:  # do not lean further
            away = np.cross(s.eef_xmat[:, 2], [0.0, 0.0, -1.0])
            fix = fix - min(0.0, float(fix @ away)) * away / (away @ away + 1e-12)
        action[3:5] = np.clip(fix[:2], -1.0, 1.0)
        return Step(action)

    lat_err = o.lateral(p) - lateral
    if o.depth(p) < -(ahead + STAGE_GAP) + 0.01:
        # In front of the doorway: carry over everything to the stage point, then go in.
        off = np.linalg.norm((stage - p)[:2])
        low = body.lo[2] < floor + ENTRY_CLEARANCE + 0.05
        if off > (0.06 if low else 0.03):
            reach = float(np.max(body.size[:2])) / 2 + 0.02
            carry_z = max(to(stage)[2], path_top(s, s.eef_pos[:2], to(stage)[:2], obj, reach) + below + 0.04,
                          path_top(s, s.eef_pos[:2], to(stage)[:2], obj, HAND_HALF[0]) - 0.012)
            if s.eef_pos[2] < carry_z - 0.03:
                return upright(move(s.eef_pos, np.array([*s.eef_pos[:2], carry_z]), CLOSE, yaw_err))
            return upright(carry(s.eef_pos, np.array([*to(stage)[:2], carry_z]), yaw_err))
        if abs(lat_err) < 0.01 and abs(p[2] - z_in) < 0.012 and abs(yaw_err) < YAW_TOL:
            return upright(carry(s.eef_pos, to(goal)))  # lined up: straight in
        return upright(carry(s.eef_pos, to(stage), yaw_err))
    if abs(lat_err) > 0.03 or p[2] - z_in > 0.03:
        # Off the doorway's line while going in: back out to the stage point.
        return upright(carry(s.eef_pos, np.array([*to(stage)[:2], s.eef_pos[2]]), yaw_err))
    if depth - o.depth(p) > 0.006:
        return upright(carry(s.eef_pos, to(goal), yaw_err))
    if p[2] - z_release > Z_TOL:
        return upright(carry(s.eef_pos, to(np.array([*goal[:2], z_release]))))
    return Step(hold(OPEN))
