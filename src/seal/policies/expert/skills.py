"""Motion primitives on LIBERO's delta end-effector controller, written as reactive rules.

Each skill maps the current privileged `SceneState` to one 7-d action (dx, dy, dz, droll,
dpitch, dyaw, gripper) and says whether it is finished. Being a function of the state alone,
with no memory of earlier steps, a skill resumes correctly after any snapshot restore and in
any of K parallel candidates, and it retries by itself (a missed grasp re-opens and
re-descends).

Conventions (robosuite OSC_POSE): position deltas are scaled by 0.05 m per unit, rotation
deltas (world-frame axis-angle) by 0.5 rad per unit; gripper -1 opens, +1 closes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from seal.policies.expert import pan
from seal.policies.expert.motion import (HOME_YAW, POS_GAIN, YAW_GAIN, finger_yaw, holder_of, horizontal_frame,
                                         path_top, wrap, yaw_error)
from seal.sim.scene import Body, SceneState

CARRY_GAIN = 10.0  # horizontal action per metre while carrying (saturates at 10 cm)
OPEN, CLOSE = -1.0, 1.0
HOVER = 0.10  # clearance above an object before descending onto it
LIFT = 0.22  # height above the table a picked object is raised to
OPEN_WIDTH = 0.07  # finger gap that counts as open
EMPTY_WIDTH = 0.011  # finger gap of a gripper closed on nothing (~0.008)
RIM_EMPTY_WIDTH = 0.004  # below any cup wall
XY_TOL, Z_TOL = 0.008, 0.008
RELEASE_XY_TOL = 0.012  # how far the carried object's origin may be off the target when let go
YAW_TOL = 0.1  # radians of finger-axis error allowed before descending
# Panda hand geometry relative to the eef site: the fingertips reach 13 mm below it and the
# pads span 5 mm below to 12 mm above it. Going lower presses the fingertips into the table.
FINGERTIP_BELOW = 0.013
PAD_BELOW, PAD_ABOVE = 0.005, 0.012
TABLE_CLEARANCE = 0.003
# Footprint of the open hand around the eef site, in the finger-axis frame (along, across):
# the hand body spans +-10.5 cm along the finger axis from 2.2 cm above the site up; the open
# fingers hang at 3.2-6.8 cm either side. Neighbours inside it block the descent.
HAND_HALF = (0.105, 0.041)
HAND_ABOVE = 0.022
FINGER_SPAN = (0.032, 0.068, 0.014)  # inner, outer along the axis; half width across
PAD_GAP = 0.076  # free space between the open pads
TURN_COST = 1.0  # placing: penalty per radian of wrist turn, against hand-overlap penalties
# Objects picked by their rim (one finger inside, one outside the wall) rather than across.
RIM_GRASP = ("mug", "bowl")
# Upright cans: round, so grasped across from any side; the wrist need not turn at all.
ROUND = ("alphabet_soup", "tomato_sauce")
# A mug's bounding box includes its handle; the cup itself is shifted away from the handle.
# Offset (local frame, metres) from the box centre to the cup axis, measured from the
# collision geoms. Unknown mugs fall back to the box centre (the rim grasp tolerates ~2 cm).
CUP_OFFSET = {"porcelain_mug": (0.02, 0.0), "white_yellow_mug": (-0.017, 0.0)}
RIM_TURN_COST = 0.3  # per radian of wrist turn to pinch a bowl from a fixed direction instead
REACH_COST = 100.0  # per metre a pinch point lies beyond FAR_X (away from the robot)
FAR_X = 0.10  # beyond this (table frame) the arm reaching down to the table is nearly straight
RIM_NEAR = 0.03  # a hand this close to a bowl's rim (horizontally) pinches it along its current finger axis
WALL = 0.005  # half a cup wall: where the fingers centre on the rim
SLOT_MARGIN = 0.015  # a shared region's outermost origins stay this far inside it
SLOT_TOL = 0.008  # release tolerance (each of x, y) when placing into a slot of a shared region
HANDLE_BAR = 0.01  # thickness of a mug handle's outer bar (radially), ~9 mm measured
DRAWER_WALL_CLEARANCE = 0.008  # the hand's underside this far above a drawer's walls when letting go
HAND_UNDERSIDE = 0.031  # the hand's underside above the eef site (its collision mesh; HAND_ABOVE has margin)
SLIDE_CLEARANCE = 0.01  # fingertips this far above an object's top while sliding over it under an overhang
SLIDE_MARGIN = 0.015  # ... having come down this far clear of the overhang
HAND_TOP = 0.12  # the hand's top above the eef site
HANDLE_GRASP_HEIGHT = 0.62  # pinch a handle this far up the mug (fraction of its height): its upper bar


@dataclass(frozen=True)
class Knobs:
    """Per-attempt perturbations drawn by the policy (all zero for the clean expert)."""

    grasp_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))  # added to the grasp point, metres
    release_early: float = 0.0  # release this many metres above the proper height


@dataclass
class Step:
    action: np.ndarray
    done: bool = False


def in_hand(s: SceneState, obj: str) -> bool:
    """Whether ``obj`` is in the hand, by the pick check the expert asked the scene for (its
    ``privileged_atoms``): ``Held`` (each finger on it, pad or body; the default) or robosuite's
    ``Grasped`` (both pads; ``grip="pads"``, the expert of every recording before 2026-12-05)."""
    held = s.facts.get(f"Held({obj})")
    return bool(s.facts.get(f"Grasped({obj})", False) if held is None else held)


def move(eef: np.ndarray, goal: np.ndarray, gripper: float, yaw_err: float = 0.0) -> np.ndarray:
    delta = np.clip(POS_GAIN * (goal - eef), -1.0, 1.0)
    return np.array([*delta, 0.0, 0.0, np.clip(YAW_GAIN * yaw_err, -1, 1), gripper])


def carry(eef: np.ndarray, goal: np.ndarray, yaw_err: float = 0.0) -> np.ndarray:
    """`move` holding an object, braking from further out: a loaded arm coasts on for a
    centimetre or two after a hard stop, enough to knock a load against a compartment wall."""
    action = move(eef, goal, CLOSE, yaw_err)
    action[:2] = np.clip(CARRY_GAIN * (goal - eef)[:2], -1.0, 1.0)
    return action


def hold(gripper: float) -> np.ndarray:
    return np.array([0, 0, 0, 0, 0, 0, gripper], dtype=np.float64)


def _axes(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """The body's local x and y axes projected on the table (unit 2-vectors)."""
    c, si = np.cos(body.yaw), np.sin(body.yaw)
    return np.array([c, si]), np.array([-si, c])


def _is_rim(name: str) -> bool:
    return any(k in name for k in RIM_GRASP)


def footprint_centre(name: str, body: Body) -> np.ndarray:
    """(x, y) of the object's main mass: the box centre, or a mug's cup axis (not its handle)."""
    centre = body.center[:2].copy()
    offset = next((v for k, v in CUP_OFFSET.items() if k in name), None)
    if offset is not None:
        ex, ey = _axes(body)
        centre += offset[0] * ex + offset[1] * ey
    return centre


def _min_grasp_z(s: SceneState) -> float:
    """Lowest eef height that keeps the fingertips off the table."""
    return s.table_z + FINGERTIP_BELOW + TABLE_CLEARANCE


def handle(name: str, body: Body) -> tuple[np.ndarray, float] | None:
    """A mug's handle: (unit 2-vector from the cup axis toward the handle, distance from the
    cup axis to the handle's outer face); None for an object without one.

    The handle is what makes the bounding box longer one way (see `_rim_candidates`); it lies
    on the side of that axis away from the cup (`CUP_OFFSET`)."""
    if not any(k in name for k in CUP_OFFSET):
        return None
    ext = (body.local_hi - body.local_lo)[:2]
    if abs(ext[0] - ext[1]) <= 0.15 * min(ext):
        return None
    ex, ey = _axes(body)
    axis = ex if ext[0] > ext[1] else ey
    cup = footprint_centre(name, body)
    if (body.center[:2] - cup) @ axis < 0:
        axis = -axis
    corners = np.array([[x, y] for x in (body.lo[0], body.hi[0]) for y in (body.lo[1], body.hi[1])])
    # The world box's corners overshoot a turned body; its local extent along the axis does not.
    reach = min(float(np.max((corners - cup) @ axis)), float(max(ext)) - float(min(ext)) / 2)
    return axis, reach


def handle_grasp(s: SceneState, name: str) -> tuple[np.ndarray, float] | None:
    """Pinch a mug's handle from above, across it, near its top: (eef point, finger yaw).

    For putting a mug somewhere with a low ceiling (a microwave): held by the rim, the hand
    sits over the cup and cannot follow it under the roof; held by the handle, with the
    hand's long side across the handle, the hand stays outside while the cup goes in first.
    The pads close on the handle's outer bar (a few millimetres thick)."""
    body = s.bodies[name]
    h = handle(name, body)
    if h is None:
        return None
    axis, reach = h
    xy = footprint_centre(name, body) + axis * (reach - HANDLE_BAR / 2)
    z = max(body.lo[2] + HANDLE_GRASP_HEIGHT * body.size[2], _min_grasp_z(s))
    return np.array([*xy, z]), float(np.arctan2(axis[0], -axis[1]))  # finger axis across the handle


def grasp_pose(s: SceneState, name: str, knobs: Knobs, by_handle: bool = False) -> tuple[np.ndarray, float]:
    """Where the gripper centre goes to grasp ``name``, and the finger-axis yaw to use.

    Of a few candidate grasps (both rim sides; shifts along the finger axis within the slack
    the open fingers leave; the other side of a box if it fits), the one whose open hand
    overlaps other objects least wins, so the hand does not land on a neighbour's rim.
    ``by_handle``: a mug by its handle (`handle_grasp`), if it has one.
    """
    body = s.bodies[name]
    # A long-handled pan is always held by its handle: its dish is wider than the hand.
    pinches = pan.handle_grasps(s, name)
    if pinches:
        point, yaw = min(pinches, key=lambda c: c[2] + _intrusion(s, c[0], c[1], name))[:2]
        return point + knobs.grasp_offset, yaw
    by_handle = handle_grasp(s, name) if by_handle else None
    if by_handle is not None:
        point, yaw = by_handle
        return point + knobs.grasp_offset, yaw
    if _is_rim(name):
        candidates = _rim_candidates(s, name, body)
    elif _is_round(name):
        candidates = _round_candidates(s, body)
    else:
        candidates = _box_candidates(s, body)
    point, yaw = min(candidates, key=lambda c: c[2] + _intrusion(s, c[0], c[1], name))[:2]
    return point + knobs.grasp_offset, yaw


def _is_round(name: str) -> bool:
    return any(k in name for k in ROUND)


def _box_grasp_z(s: SceneState, body: Body) -> float:
    """Pads just below the top; flat objects as low as the fingertips allow."""
    return max(body.hi[2] - min(0.03, 0.5 * body.size[2]), _min_grasp_z(s))


def _round_candidates(s: SceneState, body: Body) -> list[tuple[np.ndarray, float, float]]:
    """Across the can's centre from any side: the current finger yaw first (no wrist turn),
    else one of six fixed yaws 30 degrees apart, at a small cost per radian of turn, to keep
    a finger off a neighbouring can. (Fixed, so that a target does not move as the hand turns.)
    """
    point = np.array([*body.center[:2], _box_grasp_z(s, body)])
    yaws = [finger_yaw(s)] + [HOME_YAW + k * np.pi / 6 for k in range(-3, 3)]
    return [(point, yaw, 0.03 * abs(yaw_error(s, yaw))) for yaw in yaws]


def _box_candidates(s: SceneState, body: Body) -> list[tuple[np.ndarray, float, float]]:
    """(point, yaw, preference cost): across the narrow side first, centred first.

    Sides and widths are the object's horizontal ones whichever way its own frame points (a
    ketchup bottle's frame has its long axis along local y), and the width between the pads
    is the object's at the height they close (a bottle's cap, not its body)."""
    centre = body.center
    z = _box_grasp_z(s, body)
    yaw0, ext = horizontal_frame(body)
    narrow, wide = (0.0, np.pi / 2) if ext[0] <= ext[1] else (np.pi / 2, 0.0)
    out = []
    for turn, cost in ((narrow, 0.0), (wide, 0.05)):
        yaw = yaw0 + turn
        across = _slice_width(body, yaw, z)  # object width between the fingers
        if across is None:
            across = ext[0] if turn == 0.0 else ext[1]
        slack = (PAD_GAP - across) / 2 - 0.006
        if slack < 0:
            continue
        axis = np.array([np.cos(yaw), np.sin(yaw)])
        for shift in np.linspace(-slack, slack, 5) if slack > 0.004 else (0.0,):
            xy = centre[:2] + shift * axis
            out.append((np.array([*xy, z]), yaw, cost + abs(shift)))
    if not out:  # wider than the open hand both ways: try anyway, across the narrow side
        out.append((np.array([*centre[:2], z]), yaw0 + narrow, 0.0))
    return out


def _slice_width(body: Body, yaw: float, z: float) -> float | None:
    """The object's extent along finger yaw ``yaw`` over the height the pads cover with the
    eef site at ``z`` (None without per-geom parts, or if no part is at that height)."""
    axis = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    lo_z, hi_z = z - PAD_BELOW, z + PAD_ABOVE
    lo, hi = np.inf, -np.inf
    for box in body.parts:
        if box.hi[2] < lo_z or box.lo[2] > hi_z:
            continue
        c = float(box.center @ axis)
        r = float(np.abs(box.xmat.T @ axis) @ box.half)
        lo, hi = min(lo, c - r), max(hi, c + r)
    return None if hi < lo else hi - lo


def _intrusion(s: SceneState, point: np.ndarray, yaw: float, own: str, skip: tuple = ()) -> float:
    """How much other objects' boxes overlap the open hand at ``point`` (a penalty, ~m^2 x 1e3)."""
    axis = np.array([np.cos(yaw), np.sin(yaw)])
    perp = np.array([-axis[1], axis[0]])
    total = 0.0
    for n, b in s.bodies.items():
        if n == own or n in skip or b.lo[2] > point[2] + 0.13:
            continue
        corners = np.array([[x, y] for x in (b.lo[0], b.hi[0]) for y in (b.lo[1], b.hi[1])]) - point[:2]
        along, across = corners @ axis, corners @ perp
        if b.hi[2] > point[2] + HAND_ABOVE:
            total += _overlap(along, -HAND_HALF[0], HAND_HALF[0]) * _overlap(across, -HAND_HALF[1], HAND_HALF[1])
        if b.hi[2] > point[2] - FINGERTIP_BELOW:
            inner, outer, half = FINGER_SPAN
            fingers = _overlap(along, inner, outer) + _overlap(along, -outer, -inner)
            total += fingers * _overlap(across, -half, half)
    return 1e3 * total


def _overlap(values: np.ndarray, lo: float, hi: float) -> float:
    return max(0.0, min(values.max(), hi) - max(values.min(), lo))


def _rim_candidates(s: SceneState, name: str, body: Body) -> list[tuple[np.ndarray, float, float]]:
    """Pinch a cup's wall from above, closing radially; either side of the cup.

    A mug is wider than the open gripper, so one finger goes inside. With a handle (one
    horizontal extent clearly longer) the pinch is across the handle axis, where the wall
    faces the fingers squarely; a round bowl is pinched on the side toward the gripper.
    """
    cup = footprint_centre(name, body)
    ext = (body.local_hi - body.local_lo)[:2]
    ex, ey = _axes(body)
    if abs(ext[0] - ext[1]) > 0.15 * min(ext):
        radial = ey if ext[0] > ext[1] else ex  # perpendicular to the handle axis
    else:
        radial = s.eef_pos[:2] - cup
        if np.linalg.norm(radial) < min(ext) / 2 + RIM_NEAR:  # over the bowl or its rim
            # The hand is over the bowl: the direction to it is ill-defined and swings with
            # every centimetre the hand moves (the target yaw then flips between half-turn
            # twins within one chunk and the wrist stalls; hovering over a rim point, each
            # turn of the wrist shifts the hand and so the point). Pinch along the current
            # finger axis.
            radial = s.finger_axis[:2].copy()
        radial = radial / (np.linalg.norm(radial) + 1e-9)
    radius = min(ext) / 2
    z = max(body.hi[2] - min(0.02, 0.5 * body.size[2]), _min_grasp_z(s))
    sides = [radial, -radial]
    round_bowl = abs(ext[0] - ext[1]) <= 0.15 * min(ext)
    if round_bowl:
        # A round bowl can be pinched anywhere on its rim: also from fixed directions (fixed,
        # so the target does not turn with the wrist), for when a neighbour crowds the hand
        # on both sides along the current axis.
        sides += [np.array([np.cos(k * np.pi / 4), np.sin(k * np.pi / 4)]) for k in range(8)]
    out = []
    for i, side in enumerate(sides):
        xy = cup + side * (radius - WALL)
        yaw = float(np.arctan2(side[1], side[0]))
        near = 0.01 * np.linalg.norm(xy - s.eef_pos[:2])  # tie-break: the nearer side
        if i >= 2:
            near += RIM_TURN_COST * abs(yaw_error(s, yaw))  # a wrist turn, only if it helps
        if round_bowl:
            # Far out from the robot (it stands at -x) the arm is nearly straight: its elbow
            # locks and it cannot lift what it holds.
            near += REACH_COST * max(0.0, float(xy[0]) - FAR_X)
        out.append((np.array([*xy, z]), yaw, near))
    return out


def pick(s: SceneState, name: str, knobs: Knobs, by_handle: bool = False) -> Step:
    body = s.bodies[name]
    if in_hand(s, name):
        if body.lo[2] < s.table_z + 0.04:
            # Held under an overhang (grasped after `_slide_under`): back out from under it
            # first, just off the table, then lift.
            out = _overhang_entry(s, name, body, s.eef_pos, finger_yaw(s))
            if out is not None:
                return Step(move(s.eef_pos, np.array([*out[:2], s.eef_pos[2]]) + [0, 0, 0.005], CLOSE))
        return _lift_by_handle(s, body) if pan.is_pan(name) else _lift(s, body)
    by_handle = (by_handle and handle(name, body) is not None) or pan.is_pan(name)
    point, yaw = grasp_pose(s, name, knobs, by_handle)
    yaw_err = yaw_error(s, yaw)
    err = point - s.eef_pos
    xy_err = float(np.linalg.norm(err[:2]))
    # A pinched cup wall is only a few millimetres thick, as thin as an empty grip: for rim
    # grasps only a fully shut gripper counts as a miss (the Grasped fact follows shortly).
    # A box or can is held across its full width: fingers closed well past it without a
    # grasp pinched only an edge or a corner (or closed on nothing).
    empty = RIM_EMPTY_WIDTH if _is_rim(name) or by_handle else max(EMPTY_WIDTH, _grip_width(name, body, yaw, point[2]) - 0.005)
    # At the grasp point (a flat object's pads must come fully down, or they pass over it);
    # or a little above it with the pads already well down the object's sides, where rubbing
    # fingers can stall the last millimetres of the descent.
    z_tol = min(Z_TOL, 0.25 * body.size[2])
    pads_around = err[2] < 0 and -err[2] < 2 * Z_TOL and s.eef_pos[2] < body.hi[2] - 0.015
    if xy_err < XY_TOL and (abs(err[2]) < z_tol or pads_around):
        if s.gripper_width < empty:  # missed: back off (re-opens above) and try again
            return Step(move(s.eef_pos, s.eef_pos + [0, 0, 0.03], OPEN))
        # Close while holding the grasp point: a zero delta does not hold the arm (the
        # controller's goal follows it), and squeezing fingers push the hand up and away.
        return Step(move(s.eef_pos, point, CLOSE))
    if s.gripper_width < OPEN_WIDTH:
        # Still closing near the grasp point: keep closing; anywhere else: open first, rising
        # so that a re-opening hand does not drag the object.
        if xy_err < 2 * XY_TOL and abs(err[2]) < 2 * Z_TOL and s.gripper_width > empty:
            return Step(move(s.eef_pos, point, CLOSE))
        return Step(move(s.eef_pos, s.eef_pos + [0, 0, 0.01], OPEN))
    entry = _overhang_entry(s, name, body, point, yaw)
    if entry is not None:
        step = _slide_under(s, name, body, point, entry, yaw_err)
        if step is not None:
            return step
    # Hover above the grasp, high enough that the fingertips pass over whatever lies between.
    over = path_top(s, s.eef_pos[:2], point[:2], name, FINGER_SPAN[1]) + FINGERTIP_BELOW + 0.02
    hover = np.array([point[0], point[1], max(point[2] + HOVER, body.hi[2] + 0.05, over)])
    # Descend once lined up; once on the way down (below hover) tolerate a little more drift,
    # which the descent corrects, instead of bouncing back up.
    descending = s.eef_pos[2] < hover[2] - 0.02 and xy_err < 0.025 and abs(yaw_err) < 2 * YAW_TOL
    if (xy_err < 0.015 and abs(yaw_err) < YAW_TOL) or descending:
        return Step(move(s.eef_pos, _descent_goal(s, name, body, point, yaw, by_handle), OPEN, yaw_err))
    # Not lined up: line up at hover height (rising first if low, to clear the object).
    if s.eef_pos[2] < hover[2] - 0.03 and xy_err > 0.03:
        return Step(move(s.eef_pos, np.array([*s.eef_pos[:2], hover[2]]), OPEN, yaw_err))
    return Step(move(s.eef_pos, hover, OPEN, yaw_err))


def _overhang_entry(s: SceneState, name: str, body: Body, point: np.ndarray, yaw: float) -> np.ndarray | None:
    """Where to come down beside the grasp when something hangs over it (an open drawer).

    The hand is 21 cm long: grasping an object just in front of an open drawer, the hand's
    end would sit under the drawer, but coming straight down it hits the drawer on the way.
    So the hand comes down where its footprint is clear of the overhanging part, with the
    fingertips just above the object's top, and slides in over the object (under the part).
    Returns that point (eef, at the sliding height), or None if nothing overhangs.
    Overhangs are the moving parts of articulated fixtures whose underside is above the
    object; a fixed body's box says nothing about what is under it."""
    axis = np.array([np.cos(yaw), np.sin(yaw)])
    perp = np.array([-axis[1], axis[0]])
    slide_z = body.hi[2] + FINGERTIP_BELOW + SLIDE_CLEARANCE
    best, best_cost = None, np.inf
    for a in s.articulations.values():
        part = a.part
        if not slide_z + 0.05 < part.lo[2] < slide_z + HOVER + HAND_TOP:
            continue
        corners = np.array([[x, y] for x in (part.lo[0], part.hi[0]) for y in (part.lo[1], part.hi[1])]) - point[:2]
        along, across = corners @ axis, corners @ perp
        if _overlap(along, -HAND_HALF[0], HAND_HALF[0]) <= 0 or _overlap(across, -HAND_HALF[1], HAND_HALF[1]) <= 0:
            continue
        # Shortest slides (along or across the finger axis, either way) that clear the part.
        for direction, coords, half in ((axis, along, HAND_HALF[0]), (perp, across, HAND_HALF[1])):
            for sign in (1.0, -1.0):
                # Moving the hand by -sign * direction * d leaves the part all beyond its end.
                d = half - float(np.min(sign * coords)) + SLIDE_MARGIN
                xy = point[:2] - sign * direction * d
                cost = d + _intrusion(s, np.array([*xy, slide_z]), yaw, name)
                if cost < best_cost:
                    best, best_cost = np.array([*xy, slide_z]), cost
    return best


def _slide_under(s: SceneState, name: str, body: Body, point: np.ndarray, entry: np.ndarray,
                 yaw_err: float) -> Step | None:
    """Reach a grasp under an overhang: down at ``entry``, then across at the sliding height
    to above the grasp point, where the normal descent takes over (None: let it)."""
    xy_err = float(np.linalg.norm(point[:2] - s.eef_pos[:2]))
    if xy_err < 0.015 and s.eef_pos[2] < entry[2] + 0.015:
        return None  # over the object, under the overhang: straight down onto the grasp
    span = entry[:2] - point[:2]
    length = float(np.linalg.norm(span))
    u = span / (length + 1e-12)
    rel = s.eef_pos[:2] - point[:2]
    t, off = float(rel @ u), float(abs(rel @ np.array([-u[1], u[0]])))
    level = abs(s.eef_pos[2] - entry[2]) < 0.015
    if level and off < 0.012 and -0.01 < t < length + 0.012 and abs(yaw_err) < YAW_TOL:
        return Step(move(s.eef_pos, np.array([*point[:2], entry[2]]), OPEN, yaw_err))  # slide in
    at_entry = float(np.linalg.norm(entry[:2] - s.eef_pos[:2]))
    if at_entry < 0.015 and abs(yaw_err) < YAW_TOL and s.eef_pos[2] > entry[2] - 0.015:
        return Step(move(s.eef_pos, entry, OPEN, yaw_err))  # down beside it
    over = path_top(s, s.eef_pos[:2], entry[:2], name, FINGER_SPAN[1]) + FINGERTIP_BELOW + 0.02
    hover = np.array([entry[0], entry[1], max(entry[2] + HOVER, over)])
    if s.eef_pos[2] < hover[2] - 0.03 and at_entry > 0.03:
        return Step(move(s.eef_pos, np.array([*s.eef_pos[:2], hover[2]]), OPEN, yaw_err))
    return Step(move(s.eef_pos, hover, OPEN, yaw_err))


def _descent_goal(s: SceneState, name: str, body: Body, point: np.ndarray, yaw: float,
                  by_handle: bool = False) -> np.ndarray:
    """The grasp point, or a point just above the object until the hand is centred on it.

    The open fingers leave only millimetres of slack around a can: a finger that passes the
    top while still off-centre along the finger axis lands on the object and tips it over.
    So the fingertips stay above the object's top until the along-axis error fits the slack.
    """
    err = point[:2] - s.eef_pos[:2]
    axis = np.array([np.cos(yaw), np.sin(yaw)])
    along, across = abs(err @ axis), abs(err @ np.array([-axis[1], axis[0]]))
    # A handle is narrow (a mug's bar, a pan's 2.5 cm): the open fingers have centimetres of room.
    tol = 0.012 if by_handle else _along_tolerance(name, body, yaw, point[2])
    if along < tol and across < XY_TOL:
        return point
    return np.array([*point[:2], max(point[2], body.hi[2] + FINGERTIP_BELOW + 0.01)])


def _along_tolerance(name: str, body: Body, yaw: float, z: float | None = None) -> float:
    """How far off-centre along the finger axis the fingers may pass the object's top."""
    if _is_rim(name):
        return 0.012  # one finger goes inside the cup: centimetres of room
    return float(np.clip(0.6 * (PAD_GAP - _grip_width(name, body, yaw, z)) / 2, 0.003, XY_TOL))


def _grip_width(name: str, body: Body, yaw: float, z: float | None = None) -> float:
    """The object's width between the pads when grasped across at finger yaw ``yaw`` (with the
    eef site at height ``z``: where the pads close, e.g. on a bottle's narrow cap)."""
    ext = body.local_hi - body.local_lo
    if _is_round(name):
        return float(min(ext))  # the can's diameter
    if z is not None:
        width = _slice_width(body, yaw, z)
        if width is not None:
            return width
    yaw0, hext = horizontal_frame(body)
    return float(hext[0] if abs(wrap(yaw - yaw0)) < np.pi / 4 else hext[1])


def _lift(s: SceneState, body: Body) -> Step:
    lift = s.table_z + LIFT  # absolute: the grasp point rises with the object
    # Done once clearly off the table (placing raises it further as the path needs); the full
    # lift height is not always reachable, e.g. close to the robot's base.
    if body.lo[2] > s.table_z + 0.08 or (body.lo[2] > s.table_z + 0.06 and s.eef_pos[2] > lift - 0.04):
        return Step(hold(CLOSE), done=True)
    return Step(move(s.eef_pos, np.array([*s.eef_pos[:2], lift]), CLOSE))


def _lift_by_handle(s: SceneState, body: Body) -> Step:
    """Lift a pan held at its handle: slowly, leaning the hand against the dish's droop (its
    weight turns the handle in the pads). If it droops too far anyway, let go: the dish falls
    back flat from a few centimetres and the pick starts over."""
    if pan.tilt(body) > pan.MAX_DROOP:
        return Step(move(s.eef_pos, s.eef_pos, OPEN))
    step = _lift(s, body)
    step.action[2] = min(step.action[2], pan.LIFT_RATE)
    if not step.done:
        step.action[3:5] = pan.leveling(s, body)
    return step


def place_point(s: SceneState, obj: str, target: str) -> tuple[np.ndarray, float]:
    """(x, y) to release over, and the height the carried object's bottom should reach."""
    if target in s.bodies:  # On(x, plate_1): rest on top of another object
        t = s.bodies[target]
        return np.array([*t.pos[:2], 0.0]), t.hi[2] + 0.01
    site = s.sites[target]
    half = np.abs(site.xmat) @ site.size  # world-frame half extents of the region box
    floor = max(site.pos[2] - half[2], s.table_z)  # table regions may sit below the top
    # Containers (basket, caddy, microwave): let go just above the rim of whatever holds it.
    owner = max((n for n in s.bodies if target.startswith(n + "_")), key=len, default=None)
    if owner is not None and target.endswith("contain_region"):
        floor = s.bodies[owner].hi[2] - 0.02
    return np.array([*site.pos[:2], 0.0]), floor + 0.01


def _placed(s: SceneState, obj: str, target: str) -> bool:
    return s.facts.get(f"In({obj}, {target})", False) or s.facts.get(f"On({obj}, {target})", False)


def slot_point(s: SceneState, obj: str, target: str, slot: tuple[int, int]) -> np.ndarray:
    """Where the origin of the ``slot[0]``-th of ``slot[1]`` objects sharing one region goes.

    Aimed at the centre, the second moka pot lands on the first and topples. So the objects
    are lined up along the region's axis with the most room to spare for them, each origin
    kept inside the region (LIBERO tests origins) by a margin; the first goes farthest from
    the robot, so later ones are not carried over it."""
    i, n = slot
    site = s.sites[target]
    half = (np.abs(site.xmat) @ site.size)[:2]
    axis = _slot_axis(s, target)
    usable = max(half[axis] - SLOT_MARGIN, 0.0)
    if target.endswith("contain_region"):
        # Inside a container the whole object must clear the walls, not just its origin:
        # lowered against a wall, a carton catches on the rim.
        usable = max(half[axis] - float(_footprint(s.bodies[obj])[0]) / 2, 0.0)
    step = np.linspace(usable, -usable, n)[i]  # +x is away from the robot's base
    xy = site.pos[:2].copy()
    xy[axis] += step
    return xy


def _slot_axis(s: SceneState, target: str) -> int:
    """The world axis (0: x, 1: y) a shared region's slots line up along: its longer side
    (x if square). Fixed by the region alone, so that every object gets the same answer
    whatever way round it is held."""
    site = s.sites[target]
    half = (np.abs(site.xmat) @ site.size)[:2]
    return 1 if half[1] > half[0] + 1e-6 else 0


def _slot_yaw(s: SceneState, obj: str, target: str) -> float:
    """The finger yaw that turns the held object's narrow side along the slots' axis (the
    current yaw for an object about as wide as long)."""
    body = s.bodies[obj]
    ext = (body.local_hi - body.local_lo)[:2]
    now = finger_yaw(s)
    if abs(ext[0] - ext[1]) < 0.15 * min(ext):
        return now
    narrow = body.yaw + (0.0 if ext[0] <= ext[1] else np.pi / 2)
    want = 0.0 if _slot_axis(s, target) == 0 else np.pi / 2
    return now + wrap(want - narrow)


def place(s: SceneState, obj: str, target: str, knobs: Knobs, slot: tuple[int, int] | None = None) -> Step:
    body = s.bodies[obj]
    grasped = in_hand(s, obj)
    xy, bottom = place_point(s, obj, target)
    slot = slot if slot is not None and slot[1] > 1 and target in s.sites else None
    if slot is not None:
        xy = np.array([*slot_point(s, obj, target, slot), 0.0])
    if not grasped:
        # Released (or dropped): back off upwards, then hand back to thinking.
        return let_go_and_rise(s, body)
    # Steer the object's origin (not the hand) over the target: LIBERO's In/On test the
    # origin (On: within 3 cm of the support's origin), and a rim-held mug hangs several
    # centimetres off the hand.
    below = s.eef_pos[2] - body.lo[2]  # how far the object hangs below the gripper centre
    if is_tall(body) and target.endswith("contain_region") and holder_of(s, target) is not None:
        bottom = min(bottom, _lowered_bottom(s, target, below))
    release_z = bottom + below + knobs.release_early
    drawer = _drawer_joint(s, target)
    if drawer is not None:
        # The hand (21 cm long) does not fit between a drawer's walls: let go with its
        # underside just above them (a drop of a centimetre or two).
        release_z = max(release_z, drawer.part.hi[2] - HAND_ABOVE + DRAWER_WALL_CLEARANCE)
    goal, yaw = _release_pose(s, obj, target, xy[:2], release_z,
                              yaws=None if slot is None else (_slot_yaw(s, obj, target),))
    off = goal - body.pos[:2]
    goal_xy = s.eef_pos[:2] + off
    yaw_err = yaw_error(s, yaw)
    # Carry the object's bottom, and the hand, over everything on the way (the target's own
    # rim included).
    reach = float(np.max(body.size[:2])) / 2 + 0.02
    carry_z = max(release_z, path_top(s, s.eef_pos[:2], goal_xy, obj, reach) + below + 0.04,
                  path_top(s, s.eef_pos[:2], goal_xy, obj, HAND_HALF[0]) - HAND_ABOVE + 0.01)
    dist = np.linalg.norm(off)
    if dist > 0.04:  # far: rise to carrying height, then travel
        if s.eef_pos[2] < carry_z - 0.03:
            return Step(move(s.eef_pos, np.array([*s.eef_pos[:2], carry_z]), CLOSE, yaw_err))
        return Step(carry(s.eef_pos, np.array([*goal_xy, carry_z]), yaw_err))
    if _placed(s, obj, target) and knobs.release_early == 0:
        return Step(hold(OPEN))  # already counts as placed (e.g. resting on the rim): let go
    tol = _release_tolerance(s, obj, target)
    if slot is not None:  # slots are as far apart as the region allows: no slack to spare
        tol = np.minimum(tol, SLOT_TOL)
    # Off-centre, the object's bottom stays above everything near its way to the goal (a
    # basket's rim, a compartment's walls), so it cannot catch on an edge; once down there,
    # a little more drift (a swinging load) is settled in place instead of rising again.
    clear_z = path_top(s, body.pos[:2], goal, obj, reach) + below + 0.015
    low = s.eef_pos[2] < clear_z - 0.01
    if np.any(np.abs(off) > (1.5 * tol if low else tol)) or abs(yaw_err) > YAW_TOL:
        return Step(carry(s.eef_pos, np.array([*goal_xy, max(release_z, clear_z)]), yaw_err))
    if s.eef_pos[2] - release_z > Z_TOL or np.any(np.abs(off) > tol):
        return Step(carry(s.eef_pos, np.array([*goal_xy, release_z]), yaw_err))
    return Step(hold(OPEN))


TALL = 1.6  # an object is tall if its longest side is this many times its second longest
THICK = 0.025  # ... and its shortest side at least this (a box of butter is long but flat)


def is_tall(body: Body) -> bool:
    """A bottle or a carton (longest side well over the others), whichever way it lies."""
    ext = np.sort(body.local_hi - body.local_lo)[::-1]
    return bool(ext[0] >= TALL * ext[1] and ext[2] >= THICK)


def _lowered_bottom(s: SceneState, target: str, below: float) -> float:
    """How low a tall object's bottom may be lowered into a container before letting go: down
    to the floor, or as far as the hand (over its top) stays above the container's rim.

    Dropped from the rim, a carton falls its own height and topples, across the basket,
    where the next object then has no room."""
    site = s.sites[target]
    floor = site.pos[2] - float((np.abs(site.xmat) @ site.size)[2])
    rim = float(s.bodies[holder_of(s, target)].hi[2])
    return max(floor + 0.01, rim + 0.005 - HAND_ABOVE - below)


def _footprint(body: Body) -> np.ndarray:
    """World-frame (x, y) extent of an upright object, whatever its yaw: its widest horizontal side."""
    return np.full(2, float(np.max(horizontal_frame(body)[1])))


def let_go_and_rise(s: SceneState, body: Body) -> Step:
    """After a release: open fully, rise clear of the object, then report done."""
    if s.gripper_width < OPEN_WIDTH:
        return Step(move(s.eef_pos, s.eef_pos + [0, 0, 0.02], OPEN))
    clear = body.hi[2] + 0.06
    if s.eef_pos[2] < clear:
        return Step(move(s.eef_pos, np.array([*s.eef_pos[:2], clear + 0.02]), OPEN))
    return Step(hold(OPEN), done=True)


def _release_tolerance(s: SceneState, obj: str, target: str) -> np.ndarray:
    """How far (world x, y) the carried object's origin may be off its goal when let go.

    On(x, support) needs the origins within 3 cm. A region or container is more forgiving,
    but a narrow compartment only leaves the room between its walls and the object.
    """
    if target in s.bodies:
        return np.full(2, RELEASE_XY_TOL / np.sqrt(2))
    tol = np.full(2, 2 * RELEASE_XY_TOL)
    if target.endswith("contain_region"):
        site = s.sites[target]
        half = (np.abs(site.xmat) @ site.size)[:2]
        b = s.bodies[obj]
        thickness = float(np.min(b.local_hi - b.local_lo))  # the object's slimmest side
        tol = np.clip(half - thickness / 2 - 0.003, 0.006, tol)
    return tol


def _release_pose(s: SceneState, obj: str, target: str, xy: np.ndarray, release_z: float,
                  yaws: tuple[float, ...] | None = None) -> tuple[np.ndarray, float]:
    """Where the object's origin goes and the finger yaw to hold, so the hand clears neighbours.

    Candidates: the current yaw or a world-aligned one (the held object turns with the hand),
    and, for a free table region, spots within it. The least intrusion of the open hand at
    the release point wins. Turning costs enough that only a real obstruction justifies it:
    large wrist turns on top of the grasp's own turn can run the last joint into its limit,
    where the arm stalls. ``yaws``: only these yaws, at ``xy`` itself (a slot of a shared region).
    """
    body = s.bodies[obj]
    now = finger_yaw(s)
    hang = body.pos[:2] - s.eef_pos[:2]  # the object's origin relative to the hand
    if yaws is None and _drawer_joint(s, target) is not None:
        return _drawer_release_pose(s, obj, target, xy, release_z)
    spots = [(xy, 0.0)]
    if yaws is None and target in s.sites and not target.endswith("contain_region"):
        site = s.sites[target]
        half = (np.abs(site.xmat) @ site.size)[:2] - 0.02
        if holder_of(s, target) is not None:
            # Inside a fixture (a drawer, a shelf): the whole object must fit, not just its origin,
            # or it lands on a wall and tilts (a tilted bowl then jams the drawer).
            half = (np.abs(site.xmat) @ site.size)[:2] - _footprint(body) / 2 - 0.01
        spots += [(xy + np.array([dx, dy]) * np.maximum(half, 0.0), 0.02)
                  for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy]
    best, best_cost = (xy, now), np.inf
    for yaw in yaws or (now, 0.0, np.pi / 2, np.pi / 4, -np.pi / 4):
        turn = yaw_error(s, yaw)
        c, si = np.cos(turn), np.sin(turn)
        turned = np.array([c * hang[0] - si * hang[1], si * hang[0] + c * hang[1]])
        for spot, cost in spots:
            eef = np.array([*(spot - turned), release_z])
            total = cost + TURN_COST * abs(turn) + _intrusion(s, eef, yaw, obj)
            if total < best_cost:
                best, best_cost = (spot, yaw), total
    return best


def _drawer_joint(s: SceneState, target: str):
    """The slide joint of a drawer region (a cabinet's top/middle/bottom region), else None."""
    joints = [s.articulations[n] for n in s.joints_of.get(target, ()) if n in s.articulations]
    return next((a for a in joints if a.kind == "slide"), None)


def _drawer_release_pose(s: SceneState, obj: str, target: str, xy: np.ndarray,
                         release_z: float) -> tuple[np.ndarray, float]:
    """Where to let go over an open drawer, and the finger yaw: the object well inside the
    region, the hand (above the walls) clear of the cabinet's body that the drawer came out of.

    The hand's footprint is 21 x 8 cm and the cabinet's front face is only a few centimetres
    behind the region's centre, so the generic rule (least overlap with any box) is misled by
    the cabinet's box, which also contains the open drawer, and picks a spot by a wall (where
    the fingers land on it). Here the cabinet counts only up to the closed drawer's front."""
    body = s.bodies[obj]
    a = _drawer_joint(s, target)
    owner = holder_of(s, target)
    now = finger_yaw(s)
    hang = body.pos[:2] - s.eef_pos[:2]
    site = s.sites[target]
    half = np.maximum((np.abs(site.xmat) @ site.size)[:2] - _footprint(body) / 2 - 0.01, 0.0)
    # The cabinet's body: its box, cut at the drawer's front when closed (along the pull).
    pull = a.axis[:2] * (1.0 if abs(a.range[1]) >= abs(a.range[0]) else -1.0)
    pull = pull / (np.linalg.norm(pull) + 1e-12)
    opened = abs(a.qpos)
    front = max(float(c @ pull) for c in _xy_corners(a.part)) - opened
    cab = s.bodies[owner] if owner in s.bodies else None
    if cab is not None and release_z + HAND_UNDERSIDE > cab.hi[2] + 0.005:
        cab = None  # the hand passes over the cabinet's top (the top drawer): nothing to avoid
    grid = np.array([[u, v] for u in np.linspace(-HAND_HALF[0], HAND_HALF[0], 9)
                     for v in np.linspace(-HAND_HALF[1], HAND_HALF[1], 5)])
    spots = [xy + np.array([fx, fy]) * half for fx in (-1.0, 0.0, 1.0) for fy in (-1.0, 0.0, 1.0)]
    best, best_cost = (xy, now), np.inf
    for yaw in (now, 0.0, np.pi / 2, np.pi / 4, -np.pi / 4):
        turn = yaw_error(s, yaw)
        c, si = np.cos(turn), np.sin(turn)
        turned = np.array([c * hang[0] - si * hang[1], si * hang[0] + c * hang[1]])
        axis = np.array([np.cos(yaw), np.sin(yaw)])
        frame = np.stack([axis, [-axis[1], axis[0]]])  # rows: along, across the finger axis
        for spot in spots:
            eef = spot - turned
            cost = TURN_COST * abs(turn) + 0.3 * float(np.linalg.norm(spot - xy))
            if cost >= best_cost:
                continue
            if cab is not None:
                # The hand's footprint against the cabinet's body (behind the closed front).
                pts = eef + grid @ frame
                inside = (pts @ pull < front) & np.all((pts >= cab.lo[:2]) & (pts <= cab.hi[:2]), axis=1)
                cost += 50.0 * float(np.sum(front - pts[inside] @ pull))
            if cost < best_cost:
                cost += _intrusion(s, np.array([*eef, release_z]), yaw, obj, skip=(owner,))
            if cost < best_cost:
                best, best_cost = (spot, yaw), cost
    return best


def _xy_corners(box) -> np.ndarray:
    """(x, y) corners of a box's world AABB."""
    return np.array([[x, y] for x in (box.lo[0], box.hi[0]) for y in (box.lo[1], box.hi[1])])


