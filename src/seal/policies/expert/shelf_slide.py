"""Sliding a handled object onto a level of an open shelf (LIBERO's wooden two-layer shelf).

`skills.place` lowers things from above. A shelf's levels have a board over them (the
bottom level's ceiling is 9 cm above the table, the top level's 13.5 cm above the middle
board), so the hand cannot follow the object down into them. A frying pan held by the end of
its handle (`pan.handle_grasps`) can go in sideways, though: dish first through the shelf's
open side, at the level's height, with the handle pointing out so the hand stays in front of
the shelf. Let go once the dish's centre is well inside the level's region (LIBERO's In
tests the origin against the region box); the dish may stick out at the front.

The open side is a property of the fixture's model, kept in its own frame (`OPEN_SIDES`);
everything else comes from the scene: the level's floor, ceiling and width from the target
region, the shelf's front face from the fixture's box, the reach from the held object's box.
Rules are reactive, like the other skills: the action is a function of the current state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.policies.expert import pan
from seal.policies.expert.motion import path_top, yaw_error
from seal.policies.expert.skills import (
    CLOSE,
    HAND_HALF,
    OPEN,
    YAW_TOL,
    Z_TOL,
    Knobs,
    Step,
    carry,
    hold,
    in_hand,
    let_go_and_rise,
    move,
)
from seal.sim.scene import Body, SceneState

# Which way each open-fronted fixture's open side faces, in the fixture's own frame (x, y).
# wooden_two_layer_shelf: back board at local +y, side boards at local +-x, no front board.
OPEN_SIDES = {"wooden_two_layer_shelf": (0.0, -1.0)}

ENTRY_CLEARANCE = 0.02  # the object's lowest point this far above the level's floor going in
RELEASE_DROP = 0.008  # ... and this far when let go
INSIDE = 0.04  # the origin this far inside the region's front face when let go
STAGE_GAP = 0.03  # in front of the shelf: the whole object this far out of its front face
HAND_GAP = 0.02  # the hand's front stays this far out of the shelf's front face


@dataclass(frozen=True)
class Level:
    """One level of an open shelf, in the frame of its open side."""

    out: np.ndarray  # horizontal unit vector pointing out of the shelf through its open side
    along: np.ndarray  # horizontal unit vector across the opening
    front: float  # the shelf's front face: its box's furthest extent along ``out``
    region_front: float  # the target region's face on the open side, along ``out``
    region_back: float
    lateral: tuple[float, float]  # the region's extent along ``along``
    floor: float  # the region's bottom and top (the level's floor, and below its ceiling)
    ceiling: float

    def depth(self, p: np.ndarray) -> float:
        """How far ``p`` lies inside the shelf's front face (negative: in front of it)."""
        return float(self.front - p[:2] @ self.out)


def _owner(s: SceneState, target: str) -> str | None:
    return max((n for n in s.bodies if target.startswith(n + "_")), key=len, default=None)


def level(s: SceneState, obj: str, target: str) -> Level | None:
    """The shelf level ``target`` is, if the held ``obj`` is to be slid into it; else None.

    Only a pan (held by its long handle, `pan.handle_grasps`) is slid in; only a region of a
    fixture with a known open side and a board above the region (not its roof's top side)."""
    if not pan.is_pan(obj) or target not in s.sites or not target.endswith("_region"):
        return None
    owner = _owner(s, target)
    side = next((v for k, v in OPEN_SIDES.items() if owner and k in owner), None)
    if side is None:
        return None
    fixture = s.bodies[owner]
    site = s.sites[target]
    half = np.abs(site.xmat) @ site.size
    if site.pos[2] + half[2] > fixture.hi[2] - 0.003:  # nothing above it: place from above
        return None
    c, si = np.cos(fixture.yaw), np.sin(fixture.yaw)
    out = np.array([c * side[0] - si * side[1], si * side[0] + c * side[1]])
    along = np.array([-out[1], out[0]])
    corners = np.array([[x, y] for x in (fixture.lo[0], fixture.hi[0]) for y in (fixture.lo[1], fixture.hi[1])])
    front = float(np.max(corners @ out))
    centre = site.pos[:2]
    reach_out, reach_along = float(half[:2] @ np.abs(out)), float(half[:2] @ np.abs(along))
    return Level(out=out, along=along, front=front,
                 region_front=float(centre @ out) + reach_out, region_back=float(centre @ out) - reach_out,
                 lateral=(float(centre @ along) - reach_along, float(centre @ along) + reach_along),
                 floor=float(site.pos[2] - half[2]), ceiling=float(site.pos[2] + half[2]))


def _upright(s: SceneState, body: Body, action: np.ndarray) -> Step:
    action[3:5] = pan.leveling(s, body)
    return Step(action)


def slide_in(s: SceneState, obj: str, target: str, knobs: Knobs) -> Step:
    lv = level(s, obj, target)
    body = s.bodies[obj]
    if not in_hand(s, obj):
        # Let go: open, then straight up (the hand is in front of the shelf) and done.
        return let_go_and_rise(s, body)
    p = body.pos
    lowest = p[2] - body.lo[2]  # how far the object reaches below its origin (tilt included)
    corners = np.array([[x, y] for x in (body.lo[0], body.hi[0]) for y in (body.lo[1], body.hi[1])]) - p[:2]
    ahead = float(np.max(corners @ -lv.out))  # the object's far side, inward of its origin
    hand_in = float((s.eef_pos[:2] - p[:2]) @ -lv.out)  # the hand's offset inward of the origin

    # Where the origin goes: across the opening, the region's middle; in depth, INSIDE past
    # the region's front face, unless that brings the hand's front too near the shelf.
    lateral = sum(lv.lateral) / 2
    depth = lv.front - lv.region_front + INSIDE
    depth = min(depth, -(hand_in + HAND_HALF[1] + HAND_GAP))
    z_in = lv.floor + ENTRY_CLEARANCE + lowest
    z_release = lv.floor + RELEASE_DROP + lowest + knobs.release_early

    def at(lat: float, d: float, z: float) -> np.ndarray:
        xy = lv.along * lat + lv.out * (lv.front - d)
        return np.array([xy[0], xy[1], z])

    stage = at(lateral, -(ahead + STAGE_GAP), z_in)
    goal = at(lateral, depth, z_in)
    # The handle points out of the shelf: the finger axis across it runs along the opening.
    yaw_err = yaw_error(s, float(np.arctan2(lv.along[1], lv.along[0])))

    def to(obj_goal: np.ndarray) -> np.ndarray:
        return s.eef_pos + (obj_goal - p)  # the hand's goal for an object goal

    lat_err = float(p[:2] @ lv.along) - lateral
    if lv.depth(p) < -(ahead + STAGE_GAP) + 0.01:
        # In front of the shelf: carry over everything to the stage point, then go in.
        off = float(np.linalg.norm((stage - p)[:2]))
        if off > 0.03:
            reach = float(np.max(body.size[:2])) / 2 + 0.02
            below = s.eef_pos[2] - body.lo[2]
            carry_z = max(to(stage)[2], path_top(s, s.eef_pos[:2], to(stage)[:2], obj, reach) + below + 0.04)
            if s.eef_pos[2] < carry_z - 0.03:
                return _upright(s, body, move(s.eef_pos, np.array([*s.eef_pos[:2], carry_z]), CLOSE, yaw_err))
            return _upright(s, body, carry(s.eef_pos, np.array([*to(stage)[:2], carry_z]), yaw_err))
        if abs(lat_err) < 0.01 and abs(p[2] - z_in) < 0.012 and abs(yaw_err) < YAW_TOL:
            return _upright(s, body, carry(s.eef_pos, to(goal)))  # lined up: straight in
        return _upright(s, body, carry(s.eef_pos, to(stage), yaw_err))
    if abs(lat_err) > 0.03 or p[2] - z_in > 0.03:
        # Off the line while going in: back out to the stage point.
        return _upright(s, body, carry(s.eef_pos, np.array([*to(stage)[:2], s.eef_pos[2]]), yaw_err))
    if depth - lv.depth(p) > 0.006:
        return _upright(s, body, carry(s.eef_pos, to(goal), yaw_err))
    if p[2] - z_release > Z_TOL:
        return _upright(s, body, carry(s.eef_pos, to(np.array([*goal[:2], z_release]))))
    return Step(hold(OPEN))
