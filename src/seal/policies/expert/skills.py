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

from seal.sim.scene import Body, SceneState

POS_GAIN = 20.0  # action per metre of position error (saturates at 5 cm)
YAW_GAIN = 2.0  # action per radian of yaw error
OPEN, CLOSE = -1.0, 1.0
HOVER = 0.10  # clearance above an object before descending onto it
LIFT = 0.22  # height above the table a picked object is raised to
CARRY = 0.12  # clearance of a carried object above whatever it passes over
OPEN_WIDTH = 0.07  # finger gap that counts as open
EMPTY_WIDTH = 0.011  # finger gap of a gripper closed on nothing (~0.008)
XY_TOL, Z_TOL = 0.008, 0.008
YAW_TOL = 0.1  # radians of finger-axis error allowed before descending
# Panda hand geometry relative to the eef site: the fingertips reach 13 mm below it and the
# pads span 5 mm below to 12 mm above it. Going lower presses the fingertips into the table.
FINGERTIP_BELOW = 0.013
TABLE_CLEARANCE = 0.003
# Objects picked by their rim (one finger inside, one outside the wall) rather than across.
RIM_GRASP = ("mug", "bowl")
# A mug's bounding box includes its handle; the cup itself is shifted away from the handle.
# Offset (local frame, metres) from the box centre to the cup axis, measured from the
# collision geoms. Unknown mugs fall back to the box centre (the rim grasp tolerates ~2 cm).
CUP_OFFSET = {"porcelain_mug": (0.02, 0.0), "white_yellow_mug": (-0.017, 0.0)}
WALL = 0.005  # half a cup wall: where the fingers centre on the rim


@dataclass(frozen=True)
class Knobs:
    """Per-attempt perturbations drawn by the policy (all zero for the clean expert)."""

    grasp_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))  # added to the grasp point, metres
    release_early: float = 0.0  # release this many metres above the proper height


@dataclass
class Step:
    action: np.ndarray
    done: bool = False


def move(eef: np.ndarray, goal: np.ndarray, gripper: float, yaw_err: float = 0.0) -> np.ndarray:
    delta = np.clip(POS_GAIN * (goal - eef), -1.0, 1.0)
    return np.array([*delta, 0.0, 0.0, np.clip(YAW_GAIN * yaw_err, -1, 1), gripper])


def hold(gripper: float) -> np.ndarray:
    return np.array([0, 0, 0, 0, 0, 0, gripper], dtype=np.float64)


def _wrap(angle: float) -> float:
    """Into [-pi/2, pi/2): a parallel gripper is symmetric under a half turn."""
    return (angle + np.pi / 2) % np.pi - np.pi / 2


def _finger_yaw(s: SceneState) -> float:
    return float(np.arctan2(s.finger_axis[1], s.finger_axis[0]))


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


def grasp_pose(s: SceneState, name: str, knobs: Knobs) -> tuple[np.ndarray, float]:
    """Where the gripper centre goes to grasp ``name``, and the finger-axis yaw to use."""
    body = s.bodies[name]
    top = body.hi[2]
    height = body.size[2]
    if _is_rim(name):
        point, yaw = _rim_pose(s, name, body)
    else:
        centre = body.center
        point = np.array([centre[0], centre[1], top - min(0.03, 0.5 * height)])
        ext = body.local_hi - body.local_lo
        # close across the object's narrower horizontal side
        yaw = body.yaw + (0.0 if ext[0] <= ext[1] else np.pi / 2)
    point[2] = max(point[2], _min_grasp_z(s))  # flat objects: pads low, fingertips clear
    return point + knobs.grasp_offset, yaw


def _rim_pose(s: SceneState, name: str, body: Body) -> tuple[np.ndarray, float]:
    """Pinch a cup's wall from above, closing radially, on the side nearest the gripper.

    A mug is wider than the open gripper, so one finger goes inside. With a handle (one
    horizontal extent clearly longer) the pinch is across the handle axis, where the wall
    faces the fingers squarely; a round bowl is pinched toward the gripper.
    """
    cup = footprint_centre(name, body)
    ext = (body.local_hi - body.local_lo)[:2]
    ex, ey = _axes(body)
    if abs(ext[0] - ext[1]) > 0.15 * min(ext):
        radial = ey if ext[0] > ext[1] else ex  # perpendicular to the handle axis
        radius = min(ext) / 2
    else:
        radial = s.eef_pos[:2] - cup
        radial = radial / (np.linalg.norm(radial) + 1e-9)
        radius = min(ext) / 2
    if np.dot(s.eef_pos[:2] - cup, radial) < 0:
        radial = -radial
    xy = cup + radial * (radius - WALL)
    point = np.array([*xy, body.hi[2] - min(0.02, 0.5 * body.size[2])])
    return point, float(np.arctan2(radial[1], radial[0]))


def pick(s: SceneState, name: str, knobs: Knobs) -> Step:
    body = s.bodies[name]
    if s.facts.get(f"Grasped({name})", False):
        return _lift(s, body)
    point, yaw = grasp_pose(s, name, knobs)
    yaw_err = _wrap(yaw - _finger_yaw(s))
    err = point - s.eef_pos
    xy_err = float(np.linalg.norm(err[:2]))
    if xy_err < XY_TOL and abs(err[2]) < Z_TOL:  # at the grasp point
        if s.gripper_width < EMPTY_WIDTH:  # closed on nothing: back off (re-opens above)
            return Step(move(s.eef_pos, s.eef_pos + [0, 0, 0.03], OPEN))
        return Step(hold(CLOSE))
    if s.gripper_width < OPEN_WIDTH:
        # Still closing near the grasp point: keep closing; anywhere else: open first, rising
        # so that a re-opening hand does not drag the object.
        if xy_err < 2 * XY_TOL and abs(err[2]) < 2 * Z_TOL and s.gripper_width > EMPTY_WIDTH:
            return Step(hold(CLOSE))
        return Step(move(s.eef_pos, s.eef_pos + [0, 0, 0.01], OPEN))
    hover = np.array([point[0], point[1], max(point[2] + HOVER, body.hi[2] + 0.05)])
    if xy_err > 0.015 or abs(yaw_err) > YAW_TOL:
        # Not lined up: line up at hover height (rising first if low, to clear the object).
        if s.eef_pos[2] < hover[2] - 0.03 and xy_err > 0.03:
            return Step(move(s.eef_pos, np.array([*s.eef_pos[:2], hover[2]]), OPEN, yaw_err))
        if s.eef_pos[2] < body.hi[2] + 0.02 and xy_err > 0.015:
            # Low beside the object (e.g. after a miss): re-centre from above, not sideways.
            return Step(move(s.eef_pos, np.array([*s.eef_pos[:2], body.hi[2] + 0.04]), OPEN, yaw_err))
        return Step(move(s.eef_pos, hover, OPEN, yaw_err))
    return Step(move(s.eef_pos, point, OPEN, yaw_err))  # lined up: descend, still correcting


def _lift(s: SceneState, body: Body) -> Step:
    lift = s.table_z + LIFT  # absolute: the grasp point rises with the object
    if body.lo[2] > s.table_z + 0.06 and s.eef_pos[2] > lift - 0.04:
        return Step(hold(CLOSE), done=True)
    return Step(move(s.eef_pos, np.array([*s.eef_pos[:2], lift]), CLOSE))


def place_point(s: SceneState, obj: str, target: str) -> tuple[np.ndarray, float]:
    """(x, y) to release over, and the height the carried object's bottom should reach."""
    if target in s.bodies:  # On(x, plate_1): rest on top of another object
        t = s.bodies[target]
        return np.array([*footprint_centre(target, t), 0.0]), t.hi[2] + 0.01
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


def place(s: SceneState, obj: str, target: str, knobs: Knobs) -> Step:
    body = s.bodies[obj]
    grasped = s.facts.get(f"Grasped({obj})", False)
    xy, bottom = place_point(s, obj, target)
    if not grasped:
        # Released (or dropped): back off upwards, then hand back to thinking.
        if s.gripper_width < OPEN_WIDTH:
            return Step(move(s.eef_pos, s.eef_pos + [0, 0, 0.02], OPEN))
        clear = body.hi[2] + 0.06
        if s.eef_pos[2] < clear:
            return Step(move(s.eef_pos, np.array([*s.eef_pos[:2], clear + 0.02]), OPEN))
        return Step(hold(OPEN), done=True)
    # Steer the object's centre (not the hand) over the target: a rim-held mug hangs
    # several centimetres off the hand and would otherwise land on the target's edge.
    goal_xy = xy[:2] + s.eef_pos[:2] - footprint_centre(obj, body)
    below = s.eef_pos[2] - body.lo[2]  # how far the object hangs below the gripper centre
    release_z = bottom + below + knobs.release_early
    carry_z = max(release_z, _highest_between(s, obj) + below + CARRY * 0.5)
    dist = np.linalg.norm(goal_xy - s.eef_pos[:2])
    if dist > 0.04:  # far: rise to carrying height, then travel
        if s.eef_pos[2] < carry_z - 0.03:
            return Step(move(s.eef_pos, np.array([*s.eef_pos[:2], carry_z]), CLOSE))
        return Step(move(s.eef_pos, np.array([*goal_xy, carry_z]), CLOSE))
    if dist > 0.015 and s.eef_pos[2] > release_z + 0.05:  # close: centre before going down
        return Step(move(s.eef_pos, np.array([*goal_xy, s.eef_pos[2]]), CLOSE))
    if s.eef_pos[2] - release_z > Z_TOL and not (knobs.release_early == 0 and _placed(s, obj, target)):
        return Step(move(s.eef_pos, np.array([*goal_xy, release_z]), CLOSE))  # descend, correcting
    return Step(hold(OPEN))


def _highest_between(s: SceneState, carried: str) -> float:
    """Top of the tallest other object: a carried object passes above all of them."""
    tops = [b.hi[2] for n, b in s.bodies.items() if n != carried and b.hi[2] < s.table_z + 0.4]
    return max(tops, default=s.table_z)
