"""Putting a tall object (a bottle) into a drawer lying down.

LIBERO's In(x, drawer region) tests the object's origin against the region's box, which is
only a few centimetres tall: a ketchup bottle standing in the open top drawer has its origin
above the box (and sticks out above the cabinet), so it never counts as in. Lying down, its
origin is a couple of centimetres above the drawer's floor.

So the bottle, held by its cap and hanging straight down, is turned level in the air: the
hand first turns its finger axis across the drawer's long side, then tips forward about the
finger axis until it points along the long side (away from the robot), which swings the
bottle up in front of the hand. Lying level, it is lowered until the hand (pointing sideways,
its long side along the finger axis) just clears the cabinet, and let go over the part of the
drawer that is out of the cabinet; it drops flat (a few centimetres into the top drawer, about
20 cm into the bottom one) and stays level.

Rules are reactive, like the other skills: the action is a function of the current state.
"""

from __future__ import annotations

import numpy as np

from seal.policies.expert.articulated import AWAY
from seal.policies.expert.motion import (DOWN, TILT_GAIN, act, flat, hand_frame, horizontal_frame, joint_of,
                                         path_top, rotvec, unit)
from seal.policies.expert.skills import CLOSE, HAND_HALF, OPEN, OPEN_WIDTH, Step, in_hand, is_tall
from seal.sim.scene import Body, SceneState, open_sign, openness

LEVEL_TOL = 0.15  # radians of pointing error still counted as level / as pointing down
TURN_XY = 0.03  # how close (metres) the hand gets to its turning point before tipping
RELEASE_XY = 0.015  # how far the object's middle may be off its goal when let go
HAND_CLEAR = 0.012  # the level hand's lower side this far above the fixture when letting go
CARRY_CLEAR = 0.04  # the hanging object's bottom this far above anything on the way
TIPPING = 0.1  # radians off pointing down that count as tipping (the hand drifts meanwhile)
TIP_RATE = 0.5  # rotation action cap while tipping: a fast swing shakes the bottle loose


def laying_direction(s: SceneState, obj: str, target: str) -> np.ndarray | None:
    """The horizontal direction to lay ``obj`` along in ``target``, if it must lie down there.

    Only for a drawer (a region that a slide joint moves) and a tall object whose origin,
    standing on the drawer's floor, would be above the region's box. The object lies along
    the region's longer side, pointing away from the robot (the hand stays on the near side).
    """
    if target not in s.sites or obj not in s.bodies:
        return None
    joints = s.joints_of.get(target, ())
    if not joints or not all(s.articulations[j].kind == "slide" for j in joints if j in s.articulations):
        return None
    body = s.bodies[obj]
    if not is_tall(body):
        return None
    ext = np.sort(body.local_hi - body.local_lo)[::-1]
    site = s.sites[target]
    half = np.abs(site.xmat) @ site.size
    floor, top = site.pos[2] - half[2], site.pos[2] + half[2]
    if floor + ext[0] / 2 < top:
        return None
    axis = np.array([1.0, 0.0, 0.0]) if half[0] >= half[1] else np.array([0.0, 1.0, 0.0])
    if axis @ AWAY < 0 or (axis @ AWAY == 0 and site.pos[:2] @ axis[:2] < 0):
        axis = -axis
    return axis


def lay_inside(s: SceneState, obj: str, target: str) -> Step:
    d = laying_direction(s, obj, target)
    body = s.bodies[obj]
    # Across the laying direction, signed: tipping forward turns the wrist's last joint by
    # about +1.8 rad (measured) with the finger axis along UP x d, into its stop from where
    # the hand hangs after a grasp; along d x UP it ends near mid-range.
    finger = np.cross(d, [0.0, 0.0, 1.0])
    if not in_hand(s, obj):
        return _let_go_and_rise(s, body, finger)
    holder = _holder_top(s, target)
    # The bottle lies along the fingers' pointing direction, hanging or level: its middle is
    # this far ahead of the hand (a wine bottle's origin is at its bottom, not its middle).
    reach = float((body.center - s.eef_pos) @ _pointing(s))
    spot = _spot(s, target, body)
    goal_xy = spot - d[:2] * reach  # the hand's, with the bottle lying ahead of it
    release_z = holder + HAND_HALF[1] + HAND_CLEAR
    level = _tip_error(s, finger, d) < LEVEL_TOL
    xy_err = float(np.linalg.norm(goal_xy - s.eef_pos[:2]))
    if level:
        # Lying: over the drawer, down to the release height, let go.
        goal = np.array([*goal_xy, release_z])
        off = np.linalg.norm(spot - body.center[:2])
        if off < RELEASE_XY and abs(s.eef_pos[2] - release_z) < 0.01:
            return Step(_tip(s, s.eef_pos, OPEN, finger, d))
        return Step(_tip(s, goal, CLOSE, finger, d, cap=0.6))
    # Hanging: carry it to the turning point high enough that the bottle, however it hangs,
    # clears everything (it sweeps forward, never lower, while tipping), then tip. Once
    # tipping, go on tipping (the arm drifts a little while the wrist turns).
    length = float(np.max(body.local_hi - body.local_lo))
    path = path_top(s, s.eef_pos[:2], goal_xy, obj, float(np.max(body.size[:2])) / 2 + 0.02)
    turn_z = max(max(path, holder) + length + CARRY_CLEAR, release_z)
    turn = np.array([*goal_xy, turn_z])
    tilt = float(np.arccos(np.clip(-s.eef_xmat[2, 2], -1.0, 1.0)))  # pointing, off straight down
    if tilt > TIPPING and xy_err < 3 * TURN_XY:
        return Step(_tip(s, turn, CLOSE, finger, d, cap=0.6))
    if xy_err > TURN_XY or s.eef_pos[2] < turn_z - 0.03 or s.eef_xmat[:, 0] @ finger < np.cos(LEVEL_TOL):
        if s.eef_pos[2] < turn_z - 0.03 and xy_err > TURN_XY:
            turn = np.array([*s.eef_pos[:2], turn_z])  # up first
        # Signed yaw, the long way round if the short one runs into the wrist's stop.
        return Step(act(s, turn, CLOSE, finger_dir=finger, signed=True))
    return Step(_tip(s, turn, CLOSE, finger, d, cap=0.6))


def _tip(s: SceneState, goal: np.ndarray, gripper: float, finger: np.ndarray, point: np.ndarray,
         cap: float = 1.0) -> np.ndarray:
    """Move toward ``goal`` while turning the fingers to point along ``point``, the finger axis
    along ``finger`` exactly (never the half-turn twin `act_pose` may pick: that would roll
    the held bottle over), at most TIP_RATE per action."""
    action = act(s, goal, gripper, cap=cap)
    v = _tip_rotation(s, finger, point)
    action[3:6] = np.clip(TILT_GAIN * v, -TIP_RATE, TIP_RATE)
    return action


def _tip_rotation(s: SceneState, finger: np.ndarray, point: np.ndarray) -> np.ndarray:
    return rotvec(hand_frame(finger, point) @ s.eef_xmat.T)


def _tip_error(s: SceneState, finger: np.ndarray, point: np.ndarray) -> float:
    return float(np.linalg.norm(_tip_rotation(s, finger, point)))


def _spot(s: SceneState, target: str, body: Body) -> np.ndarray:
    """Where the lying object's middle goes: the region's centre, moved along the drawer's
    pull to the middle of the part that is out of the cabinet (the region runs on under the
    cabinet's face, which a bottle dropped from above would land on)."""
    site = s.sites[target]
    xy = site.pos[:2].copy()
    a = joint_of(s, target, want_open=False)
    pull = unit(flat(a.axis * open_sign(a)))[:2]
    corners = np.array([[x, y] for x in (a.part.lo[0], a.part.hi[0]) for y in (a.part.lo[1], a.part.hi[1])])
    front = float(np.max(corners @ pull))  # the drawer's front, along the pull
    out = (front - openness(a), front)  # the stretch that is out of the cabinet
    half = float(np.abs(site.xmat[:2, :2] @ site.size[:2]) @ np.abs(pull))  # the region's half depth
    centre = float(xy @ pull)
    radius = float(np.min(horizontal_frame(body)[1])) / 2
    lo = max(out[0], centre - half) + radius
    hi = min(out[1], centre + half) - radius
    along = (lo + hi) / 2 if lo <= hi else centre
    return xy + (along - centre) * pull


def _holder_top(s: SceneState, target: str) -> float:
    """Top of the fixture the region belongs to (the cabinet)."""
    owner = max((n for n in s.bodies if target.startswith(n + "_")), key=len, default=None)
    return float(s.bodies[owner].hi[2]) if owner is not None else float(s.sites[target].pos[2])


def _let_go_and_rise(s: SceneState, body: Body, finger: np.ndarray) -> Step:
    """Open, rise clear of the fixture, and tip back to pointing straight down."""
    if s.gripper_width < OPEN_WIDTH:
        return Step(_tip(s, s.eef_pos, OPEN, finger, _pointing(s)))
    clear = max(body.hi[2], _holder_top_near(s, body)) + HAND_HALF[1] + 0.05
    if s.eef_pos[2] < clear - 0.01:
        return Step(_tip(s, np.array([*s.eef_pos[:2], clear]), OPEN, finger, _pointing(s)))
    upright = _tip_error(s, finger, DOWN) < LEVEL_TOL
    return Step(_tip(s, s.eef_pos, OPEN, finger, DOWN), done=upright)


def _holder_top_near(s: SceneState, body: Body) -> float:
    """Top of the tallest thing under the hand (the cabinet the bottle went into)."""
    return path_top(s, s.eef_pos[:2], s.eef_pos[:2], "", HAND_HALF[0])


def _pointing(s: SceneState) -> np.ndarray:
    return unit(s.eef_xmat[:, 2])
