"""Sliding a held object in under a roof (a two-layer shelf's upper level), sideways.

`skills.place` lowers things from above; a shelf level 13.5 cm tall takes neither a standing
book (13.7 cm) nor the hand above it. Like `stow` (the microwave's doorway), the object goes
in through the open side, but a book held by its top edge cannot just be carried in: it
hangs down. So the hand first turns (nearly) level, pointing into the shelf, with the finger axis
horizontal and across the opening; the book turns with it and lies on its long edge ahead
of the fingers (its 11 cm width now upright, its length pointing in). Then the book is
lined up with the level's floor, slid in until the fingertips reach the opening's plane,
and let go just above the floor; the hand backs out, and points down again.

Geometry comes from the scene: the level's floor and ceiling, and which side is open, from
the fixture's own collision boxes (`SceneState.fixture_boxes`), the region from its site.
Reactive like the other skills: every action is a function of the current state alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.policies.expert.articulated import UPRIGHT_TOL
from seal.policies.expert.motion import act, act_pose, hand_tilt, holder_of, misalign, pose_error
from seal.policies.expert.skills import CLOSE, OPEN, OPEN_WIDTH, Step, hold, in_hand
from seal.sim.scene import Box, SceneState

DOWN = np.array([0.0, 0.0, -1.0])
AWAY = np.array([1.0, 0.0])  # away from the robot's base (LIBERO: the arm stands at -x)
HAND_ROOM = 0.10  # a top-down placement needs this much above the object under a ceiling
FLOOR_GAP = 0.006  # the object's underside this far above the level's floor while going in
# The fingers point this far below level: the wrist, 22 cm behind the fingertips and 3 cm
# below them when level, then rises clear of the neighbours standing on the table behind
# (a 13.7 cm book stands as tall as the shelf's floor plus the lowered book).
DIP = 0.15
STAGE_GAP = 0.05  # in front of the opening: the turned object's far end this far outside
TURN_RATE = 0.3  # rotation action cap while tipping the held object over
TURNED = 0.15  # radians of pose error still counted as turned level
LINE_UP_GAP = 0.015  # the object's far end this far outside the opening while lining up
LINED_UP = 0.01  # metres of height / lateral error allowed before going in
OFF_LINE = 0.025  # ... and while going in, before backing out to line up again
IN_PAST_FACE = 0.01  # the eef goes this far in past the opening's plane
BACK_OUT = 0.06  # after letting go: back out until the fingertips are this far outside
RISE_TO = 0.12  # then rise this far above the ceiling, pointing down again


@dataclass(frozen=True)
class Level:
    """A roofed region: its floor and ceiling, and the open side it is entered from."""

    inward: np.ndarray  # (3,) horizontal unit vector into the region from its open side
    face: np.ndarray  # (3,) a point on the open side's plane (the region's face there)
    floor: float
    ceiling: float
    centre: np.ndarray  # (3,) region centre
    half: np.ndarray  # (3,) world half extents of the region box

    def depth(self, p: np.ndarray) -> float:
        """How far ``p`` is in past the opening's plane (negative: outside)."""
        return float((p - self.face)[:2] @ self.inward[:2])

    def lateral(self, p: np.ndarray) -> float:
        side = np.array([-self.inward[1], self.inward[0]])
        return float((p - self.centre)[:2] @ side)

    @property
    def across(self) -> np.ndarray:
        return np.array([-self.inward[1], self.inward[0], 0.0])


def _inside(box: Box, p: np.ndarray) -> bool:
    return bool(np.all(np.abs(box.xmat.T @ (p - box.center)) <= box.half))


def level(s: SceneState, target: str) -> Level | None:
    """The roofed level ``target`` is, if it is one: a region of a static fixture with part of
    the fixture right above it and exactly one of its sides open."""
    if target not in s.sites or target.endswith("contain_region") or target in s.joints_of:
        return None
    holder = holder_of(s, target)
    boxes = s.fixture_boxes.get(holder or "", ())
    if not boxes:
        return None
    site = s.sites[target]
    half = np.abs(site.xmat) @ site.size
    centre = site.pos
    floor = centre[2] - half[2]
    inner_lo, inner_hi = centre[:2] - half[:2] + 0.01, centre[:2] + half[:2] - 0.01
    above = [b.lo[2] for b in boxes if b.lo[2] > floor + 0.02
             and np.all(b.lo[:2] < inner_hi) and np.all(b.hi[:2] > inner_lo)]
    if not above:
        return None
    ceiling = float(min(above))
    # Which sides are open: sample points just outside each face, at mid-height.
    sides = []
    for axis in (0, 1):
        for sign in (-1.0, 1.0):
            out = np.zeros(3)
            out[axis] = sign
            other = 1 - axis
            samples = []
            for t in np.linspace(-0.8, 0.8, 9):
                p = centre.copy()
                p[axis] += sign * (half[axis] + 0.015)
                p[other] += t * half[other]
                p[2] = (floor + ceiling) / 2
                samples.append(p)
            blocked = sum(any(_inside(b, p) for b in boxes) for p in samples)
            if blocked <= 1:
                sides.append(out)
    if not sides:
        return None
    outward = max(sides, key=lambda o: -float(o[:2] @ AWAY))  # the side facing the robot
    inward = -outward
    face = centre - inward * float(np.abs(half) @ np.abs(inward))
    return Level(inward=inward, face=face, floor=float(floor), ceiling=ceiling, centre=centre.copy(), half=half)


def under_roof(s: SceneState, obj: str, target: str | None) -> Level | None:
    """The level to slide ``obj`` into, if ``target`` is roofed too low to place it from above."""
    if target is None or obj not in s.bodies:
        return None
    lv = level(s, target)
    body = s.bodies[obj]
    if lv is None or lv.ceiling - lv.floor > float(body.size[2]) + HAND_ROOM:
        return None
    # Turned level, the object stands on its side, as tall as its widest horizontal extent:
    # a level lower than that (the shelf's 7 cm bottom level) it cannot be carried into.
    room = lv.ceiling - max(lv.floor, s.table_z) - FLOOR_GAP
    if float(np.max(body.local_hi[:2] - body.local_lo[:2])) > room:
        return None
    return lv


def place_under_roof(s: SceneState, obj: str, target: str, knobs) -> Step:
    lv = under_roof(s, obj, target)
    body = s.bodies[obj]
    finger = lv.across
    point = lv.inward * np.cos(DIP) + DOWN * np.sin(DIP)
    if not in_hand(s, obj):
        return _retreat(s, lv)
    p = s.eef_pos
    # How far the object reaches ahead of the hand once turned: up to its whole height.
    reach = float(np.max(body.size))
    stage_depth = -(reach + STAGE_GAP)
    lat_goal = lv.lateral(p) - lv.lateral(body.center)  # the object's box centred on the region
    turned = pose_error(s, finger, point) < TURNED
    if not turned:
        # Turn level in front of the opening, high enough that the hanging object swings clear
        # of the table; keep pointing down until there (turning far out stalls the arm).
        high = max(s.table_z + reach + 0.06, lv.floor + 0.05 + reach / 2)
        stage = _point(lv, lat_goal, stage_depth, high)
        off = max(float(np.linalg.norm((stage - p)[:2])), abs(stage[2] - p[2]))
        turning = hand_tilt(s) > 0.3 and off < 0.12  # already swinging round: finish the turn
        if off > 0.05 and not turning:
            if p[2] < high - 0.03 and lv.depth(p) > stage_depth - 0.02:
                return Step(act(s, np.array([*p[:2], high]), CLOSE, finger, DOWN))
            return Step(act(s, stage, CLOSE, finger, DOWN))
        if misalign(s, finger) > TURNED:  # first the finger axis across, still pointing down
            return Step(act(s, stage, CLOSE, finger, DOWN))
        # Then tip over slowly: a fast swing flings a 14 cm book out of a pinch at its edge.
        action = act_pose(s, stage, CLOSE, finger, point, cap=0.5)
        action[3:6] *= min(1.0, TURN_RATE / (np.abs(action[3:6]).max() + 1e-9))
        return Step(action)
    # Turned: the object's underside just above the floor, its box centred across the opening.
    dz = lv.floor + FLOOR_GAP + knobs.release_early - body.lo[2]
    z_goal = p[2] + dz
    lat_err = lv.lateral(body.center)
    ahead = float(np.max([(c - p)[:2] @ lv.inward[:2] for c in _corners(body)]))  # far end, past the eef
    far_end = lv.depth(p) + ahead
    goal_depth = IN_PAST_FACE
    if far_end < 0.0:
        # Outside: line up in front of the opening (the far end clear of its plane), then in.
        if abs(lat_err) < LINED_UP and abs(dz) < LINED_UP:
            return Step(act_pose(s, _point(lv, lat_goal, goal_depth, z_goal), CLOSE, finger, point, cap=0.5))
        # Line up close to the opening: the wrist, 22 cm behind the fingers, then stays clear
        # of whatever stands on the table further out.
        depth = -(ahead + LINE_UP_GAP)
        return Step(act_pose(s, _point(lv, lat_goal, depth, z_goal), CLOSE, finger, point, cap=0.5))
    if abs(lat_err) > OFF_LINE or abs(dz) > OFF_LINE:
        # Off line while going in: back straight out.
        back = _point(lv, lv.lateral(p), -(ahead + 0.03), p[2])
        return Step(act_pose(s, back, CLOSE, finger, point, cap=0.5))
    if goal_depth - lv.depth(p) > 0.006:
        return Step(act_pose(s, _point(lv, lat_goal, goal_depth, z_goal), CLOSE, finger, point, cap=0.5))
    return Step(hold(OPEN))


def _point(lv: Level, lateral: float, depth: float, z: float) -> np.ndarray:
    """The world point at ``lateral`` across and ``depth`` in from the opening, height ``z``."""
    p = lv.face + lv.inward * depth + lv.across * (lateral - lv.lateral(lv.face))
    return np.array([p[0], p[1], z])


def _corners(body) -> np.ndarray:
    return np.array([[x, y, z] for x in (body.lo[0], body.hi[0]) for y in (body.lo[1], body.hi[1])
                     for z in (body.lo[2], body.hi[2])])


def _retreat(s: SceneState, lv: Level) -> Step:
    """After letting go: open fully, back straight out, then rise pointing down; done."""
    p = s.eef_pos
    if s.gripper_width < OPEN_WIDTH:
        return Step(hold(OPEN))
    if lv.depth(p) > -BACK_OUT and hand_tilt(s) > UPRIGHT_TOL:
        return Step(act_pose(s, _point(lv, lv.lateral(p), -BACK_OUT - 0.02, p[2]), OPEN, lv.across, lv.inward, cap=0.5))
    high = max(lv.ceiling, s.table_z) + RISE_TO
    if p[2] < high - 0.02 or hand_tilt(s) > UPRIGHT_TOL:
        return Step(act(s, np.array([*p[:2], high]), OPEN, None, DOWN))
    return Step(hold(OPEN), done=True)
