"""Motion primitives for articulated fixtures: drawers, the microwave door, the stove knob.

Each maps (scene, LIBERO name, sub-goal atom) to a `skills.Step`, reactively, like
`skills.pick`/`skills.place`: the action is a function of the current `SceneState` alone, so a
skill resumes after any snapshot restore, and a slipped push or grasp is retried by itself
(the rules see the gripper out of place and bring it back). Every rule also holds on the
policy's kinematically extrapolated scenes, where only the gripper moves: "holding" and
"pushing" windows reach ahead of the fixture by what a chunk can move the gripper.

Geometry comes from `SceneState.articulations` (joint axis and anchor, the moving part's
collision boxes), never from per-task constants:

* drawer (slide joint): the handle is the part's geometry sticking out furthest along the
  pull direction. Close: closed fingers push the handle in, leaning toward the cabinet so
  the forearm stays off the cabinet's top. Open: with the gripper level (pointing into the
  cabinet), pinch the bar from above and below and pull (top and middle drawers); a bottom
  drawer's bar is too near the table for that: press the fingertips on it and drag it out.
* door (hinge joint, microwave_1): the handle is the part's geometry furthest from the hinge.
  Close: closed fingers push the outer face along its arc, high up so the wide hand passes
  over the door's top edge. Open: pinch the handle's top and pull it round as far as the arm
  reaches comfortably, then push the rest of the way from the inside.
* knob (hinge, flat_stove_1): grip the ridge across, twist the wrist, let go.

Every skill ends with the gripper backed away from the fixture and pointing straight down
again, so the next skill (which steers only yaw) starts clean.

LIBERO's convention: a fixture is closed / off near ``qpos == 0`` and opens toward the far end
of its joint range. Whether the sub-goal holds is read from ``scene.facts[str(goal)]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.policies.expert.motion import (DOWN, UP, act, act_pose, flat, hand_tilt, joint_of, misalign, pose_error,
                                         unit, wrist_side, yaw_toward)
from seal.policies.expert.skills import CLOSE, OPEN, OPEN_WIDTH, Step
from seal.sim.goals import GoalAtom
from seal.sim.scene import Articulation, Box, SceneState, open_sign, openness

# Gripper geometry (Panda, measured in the eef site's frame).
FINGER_HALF = 0.012  # half thickness of the closed fingers across the finger axis (+ margin)
HAND_ABOVE_EEF = 0.026  # the hand's underside sits this far above the end-effector site
AWAY = np.array([1.0, 0.0, 0.0])  # away from the robot's base (LIBERO: the arm stands at -x)
ELBOW_LOCKED = -0.35  # Panda joint 4 above this (stop at -0.07): the arm is nearly straight
UNLOCK_LEAN = 0.6  # radians to lean the fingers toward the robot to bend a straight elbow

# Motion.
CLEARANCE = 0.06  # how far the gripper backs away from a fixture before a skill is done
PUSH_SPEED = 0.6  # action cap while pushing or pulling (~7 mm/step): firm, not violent
YAW_TOL = 0.15  # finger-axis alignment needed before going down next to a fixture
UPRIGHT_TOL = 0.1  # radians of tilt still counted as pointing straight down

# Drawers.
DRAWER_TILT = 0.5  # radians the fingers lean toward a drawer while pushing it
LEVEL_YAW = 0.5  # the level gripper points this far off straight-in, away from the robot
GRIP_OUT = 0.006  # eef this far out from the bar's centre to pinch it: pads on it, tips short of the face
LEVEL_CLEARANCE = 0.12  # height to rise to, level, before pointing down again (the hand swings)
OPEN_TO = 0.155  # how far to pull a drawer (LIBERO: open beyond 0.14 of its 0.16 travel)
SWEEP_CHECK_UNTIL = 0.02  # a drawer opened further than this has already swept over what is in front
SWEEP_MARGIN = 0.015  # push what is in a drawer's sweep this far clear of its open front
PUSH_SLACK = 0.04  # how far past the contact the push window reaches (a chunk's extrapolation)
LEVEL_MIN_HEIGHT = 0.09  # handle height above the table the level pinch needs (the hand reaches 10 cm below)
FINGERTIP_BELOW = 0.013  # the closed fingertips reach this far past the eef site along the pointing axis
DRAG_OUT = 0.002  # fingertips this far out from the bar's centre line when dragging a low drawer
DRAG_PRESS = 0.02  # ... pressing down toward a point this far below the bar's top
DRAG_SPEED = 0.35  # action cap while dragging: the friction has to beat the drawer's damping
DRAG_TILT = 0.8  # radians the fingers lean into the cabinet: the hand's back edge clears the handle above
DRAG_OVER = 0.02  # ... coming in over the bar this far above its top
DRAG_SLACK = 0.04  # how far ahead of the bar the drag window reaches (a chunk's extrapolated motion)

# Doors.
DOOR_LEAD = 0.25  # radians the push (or pull) target runs ahead of the door along its arc
DOOR_PULL_TO = 0.85  # radians to pull a door open by its handle before pushing it the rest of the way
DOOR_INNER_REACH = 0.75  # push a door open this far out along it (fraction of the handle's radius)
DOOR_OPEN_TO = 1.38  # radians to push a door open to (LIBERO's microwave: open beyond 1.3)
DOOR_GRIP_OUT = 0.006  # grip this far out beyond the handle's axis: the hand then clears the door's face

PUSH_IN_MARGIN = 0.012  # push what sticks out of a doorway this far behind the door's plane
PUSH_IN_HEIGHT = 0.45  # ... pressing at this fraction of its height (a mug: its handle)

# Knobs.
KNOB_GRIP_DEPTH = 0.02  # eef this far below the ridge's top: pads on the ridge, tips above the dial
KNOB_LEAD = 0.4  # radians the wrist runs ahead of the knob while twisting
KNOB_ON_AT = 0.5  # LIBERO's stove is on from qpos 0.5


# ---- geometry (shared helpers: seal.policies.expert.motion) -------------------------------
def _extent(box: Box, direction: np.ndarray) -> float:
    """How far the box reaches along ``direction`` (max of corner · direction)."""
    return float(box.center @ direction + np.abs(box.xmat.T @ direction) @ box.half)


_SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)


def _corners(box: Box) -> np.ndarray:
    """The box's 8 corners, world frame."""
    return box.center + (_SIGNS * box.half) @ box.xmat.T


def _owner(s: SceneState, name: str) -> str:
    """The fixture a region belongs to (or the name itself)."""
    return max((n for n in s.bodies if name == n or name.startswith(n + "_")), key=len, default=name)


def _travel_height(s: SceneState, lo: np.ndarray, hi: np.ndarray, floor: float, skip: str = "") -> float:
    """A height to cross the horizontal rectangle lo..hi at: above ``floor`` and above every
    object whose box overlaps it (except the fixture ``skip``)."""
    top = floor
    for name, b in s.bodies.items():
        if name != skip and b.lo[0] < hi[0] and b.hi[0] > lo[0] and b.lo[1] < hi[1] and b.hi[1] > lo[1]:
            top = max(top, b.hi[2])
    return top + 0.05


def _rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: ``v`` turned by ``angle`` about the unit ``axis``."""
    c, si = np.cos(angle), np.sin(angle)
    return v * c + np.cross(axis, v) * si + axis * (axis @ v) * (1 - c)


# ---- actions -----------------------------------------------------------------------------
def _still(s: SceneState, gripper: float) -> np.ndarray:
    """Stay put (straightening up) while the fingers open or close."""
    return act(s, s.eef_pos, gripper)


def _keep_gripper(s: SceneState) -> float:
    """Closed stays closed, open stays open (no pointless finger motion while retreating)."""
    return CLOSE if s.gripper_width < 0.04 else OPEN


# ---- moves shared by the skills ------------------------------------------------------------
def _approach(s: SceneState, ready: np.ndarray, gripper: float, finger_dir: np.ndarray, point: np.ndarray,
              a: Articulation, floor: float, skip: str, signed: bool = False) -> np.ndarray:
    """Get to ``ready`` (next to a handle) without sweeping through anything: across at a
    travel height, then straight down once turned the right way.

    The travel height clears ``floor`` and every object (but the fixture ``skip``) under the
    path or the moving part ``a``. A gripper below it goes up first; one well above it comes
    down first: far out and high the arm is nearly straight, and a move toward the robot from
    there locks its elbow at the joint stop, after which it no longer follows at all. Heights
    are absolute targets, so the arm's sag during fast moves is corrected, not accumulated."""
    if _elbow_locked(s):
        # Lean the fingers toward the robot where the gripper is: that bends the elbow off its
        # stop (measured), after which moving on straightens the gripper and keeps the bend.
        lean = unit(DOWN * np.cos(UNLOCK_LEAN) - AWAY * np.sin(UNLOCK_LEAN))
        return act(s, s.eef_pos, gripper, finger_dir, lean, signed=signed)
    err = ready - s.eef_pos
    turned = abs(yaw_toward(s, finger_dir, signed=True)) if signed else misalign(s, finger_dir)
    if np.linalg.norm(err[:2]) < 0.015 and turned < YAW_TOL:
        return act(s, ready, gripper, finger_dir, point, signed=signed)  # straight down (or up) onto it
    # Lean (if at all) only near the ready point: turning while travelling far out, too, can
    # swing the arm into that locked-elbow pose.
    if np.linalg.norm(err[:2]) > 0.05:
        point = DOWN
    lo = np.minimum.reduce([a.part.lo, s.eef_pos, ready])
    hi = np.maximum.reduce([a.part.hi, s.eef_pos, ready])
    high = max(_travel_height(s, lo, hi, floor, skip), ready[2] + 0.04)
    if abs(s.eef_pos[2] - high) > 0.03:
        return act(s, np.array([*s.eef_pos[:2], high]), gripper, finger_dir, point, signed=signed)  # up/down first
    return act(s, np.array([ready[0], ready[1], high]), gripper, finger_dir, point, signed=signed)


def _elbow_locked(s: SceneState) -> bool:
    """Whether the arm is stretched with its elbow (Panda joint 4) almost at its straight-arm
    stop, where the controller cannot bend it back by moving the gripper toward the robot."""
    return len(s.arm_qpos) >= 4 and s.arm_qpos[3] > ELBOW_LOCKED


def _back_off(s: SceneState, away: np.ndarray, ahead: float, far: float) -> Step:
    """Retreat along ``away`` until ``ahead`` (the eef's offset that way) reaches ``far``,
    straightening the gripper to point down, then report done."""
    if ahead > far - 0.01 and hand_tilt(s) < UPRIGHT_TOL:
        return Step(_still(s, _keep_gripper(s)), done=True)
    target = s.eef_pos + away * max(far - ahead, 0.0) + UP * 0.01
    return Step(act(s, target, _keep_gripper(s)))


def _rise(s: SceneState, height: float) -> Step:
    """Go up to ``height`` with the gripper straightening, then report done."""
    if s.eef_pos[2] > height - 0.01 and hand_tilt(s) < UPRIGHT_TOL:
        return Step(_still(s, _keep_gripper(s)), done=True)
    return Step(act(s, np.array([*s.eef_pos[:2], max(height, s.eef_pos[2])]), _keep_gripper(s)))


# ---- drawers -----------------------------------------------------------------------------
@dataclass(frozen=True)
class _Drawer:
    pull: np.ndarray  # horizontal unit vector the drawer slides along when opening
    side: np.ndarray  # horizontal unit vector across the drawer front
    handle: np.ndarray  # centre of the handle bar
    front: float  # outermost reach of the handle along `pull`, from the handle centre
    bar_top: float  # top of the handle bar
    bar_half: float  # half length of the handle bar (along `side`)
    top: float  # top of the drawer


def _drawer(a: Articulation) -> _Drawer:
    pull = unit(flat(a.axis * open_sign(a)))
    side = np.array([-pull[1], pull[0], 0.0])
    reach = np.array([_extent(g, pull) for g in a.geoms])
    outer = reach.max()
    bar = [g for g, r in zip(a.geoms, reach) if r > outer - 0.004]  # the handle bar
    lo = np.min([g.lo for g in bar], axis=0)
    hi = np.max([g.hi for g in bar], axis=0)
    handle = (lo + hi) / 2
    return _Drawer(pull=pull, side=side, handle=handle, front=float(outer - handle @ pull), bar_top=float(hi[2]),
                   bar_half=float(np.abs(hi - lo) @ np.abs(side)) / 2, top=float(a.part.hi[2]))


def close_drawer(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    """Push the drawer in with closed fingers on its handle; back away once it is shut.

    The fingers lean toward the cabinet while pushing: with the gripper straight down, the
    forearm runs into the cabinet's top before a low drawer is fully in."""
    a = joint_of(s, obj, want_open=False)
    g = _drawer(a)
    rel = s.eef_pos - g.handle
    ahead, lateral = rel @ g.pull, rel @ g.side  # eef offset out from / across the handle
    contact = g.front + FINGER_HALF  # `ahead` at which the fingers touch the bar
    if s.facts.get(str(goal), False):
        return _back_off(s, g.pull, ahead, contact + CLEARANCE)
    lean = unit(DOWN * np.cos(DRAWER_TILT) - g.pull * np.sin(DRAWER_TILT))
    # Push: level with the handle, in front of it or pressing on it. The target lies where the
    # fingers would be with the drawer shut (+1 cm), so the push ends against the stop.
    remaining = openness(a) + 0.01
    if abs(lateral) < 0.02 and abs(rel[2]) < 0.015 and contact - remaining - 0.02 < ahead < contact + 0.05:
        target = g.handle + g.pull * (contact - remaining)
        return Step(act(s, target, CLOSE, g.side, lean, cap=PUSH_SPEED))
    ready = g.handle + g.pull * (contact + 0.03)
    return Step(_approach(s, ready, CLOSE, g.side, lean, a, max(g.top, g.handle[2] + 0.03), _owner(s, obj)))


def open_drawer(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    """Pinch the handle bar from the front with the gripper level (pointing into the
    cabinet, fingers above and below the bar), pull the drawer out, let go, back away and
    point down again.

    With the gripper pointing down the bar cannot be held: the slot behind it is narrower
    than a finger, and straddling it along the pull would put the hand (20 cm along the
    finger axis) into the cabinet's face. Level, the hand reaches 10 cm above and below the
    bar, so this needs the handle that high above the table (top and middle drawers); a
    lower one (the bottom drawer) is dragged out by friction instead (`_drag_drawer`)."""
    a = joint_of(s, obj, want_open=True)
    g = _drawer(a)
    if g.handle[2] - s.table_z < LEVEL_MIN_HEIGHT:
        return _drag_drawer(s, obj, goal, a, g)
    rel = s.eef_pos - g.handle
    ahead, lateral, dz = rel @ g.pull, rel @ g.side, rel[2]
    point_in = unit(-g.pull * np.cos(LEVEL_YAW) + AWAY * np.sin(LEVEL_YAW))
    if s.facts.get(str(goal), False):
        if s.gripper_width < OPEN_WIDTH and ahead < GRIP_OUT + 0.03:
            return Step(act_pose(s, s.eef_pos, OPEN, UP, point_in))  # let go first
        # Slide off the end of the bar (away from the robot: backing straight out can run the
        # wrist into whatever stands behind it), go up, still level (the hand reaches 10 cm
        # below the fingers), then turn to point down again.
        off = g.side if g.side @ AWAY >= 0 else -g.side
        along = rel @ off
        if along < g.bar_half + 0.03 and dz < 0.02:
            target = s.eef_pos + off * (g.bar_half + 0.04 - along)
            return Step(act_pose(s, target, OPEN, UP, point_in))
        if dz < LEVEL_CLEARANCE - 0.01:
            target = np.array([*s.eef_pos[:2], g.handle[2] + LEVEL_CLEARANCE])
            return Step(act_pose(s, target, OPEN, UP, point_in))
        return _rise(s, s.eef_pos[2])
    near_line = abs(lateral) < 0.02 and abs(dz) < 0.02
    if near_line and -0.01 < ahead < 0.15 and 0.012 < s.gripper_width < 0.05:
        # Holding the bar: pull straight out (the window is long: the drawer comes along,
        # and the policy's chunk extrapolation moves only the gripper).
        remaining = OPEN_TO - openness(a)
        target = s.eef_pos + g.pull * max(remaining, 0.0) - g.side * lateral
        target[2] = g.handle[2]
        return Step(act_pose(s, target, CLOSE, UP, point_in, cap=PUSH_SPEED))
    grip = g.handle + g.pull * GRIP_OUT
    err = grip - s.eef_pos
    aligned = pose_error(s, UP, point_in) < 0.15
    if s.gripper_width < OPEN_WIDTH:
        if np.linalg.norm(err) < 0.012 and s.gripper_width > 0.012:
            return Step(act_pose(s, grip, CLOSE, UP, point_in))  # still closing on the bar
        # Closed on nothing, or stale: open, backing out.
        return Step(act_pose(s, s.eef_pos + g.pull * 0.01, OPEN, UP, point_in))
    if np.linalg.norm(err) < 0.006 and aligned:
        return Step(act_pose(s, grip, CLOSE, UP, point_in))  # there: pinch
    if abs(lateral) < 0.012 and abs(dz) < 0.012 and GRIP_OUT - 0.01 < ahead < GRIP_OUT + 0.14 and aligned:
        return Step(act_pose(s, grip, OPEN, UP, point_in, cap=PUSH_SPEED))  # straight in
    # Anywhere else: to a point level with the bar, out in front of it, turning level.
    return Step(act_pose(s, g.handle + g.pull * (GRIP_OUT + 0.1), OPEN, UP, point_in))


def _drag_drawer(s: SceneState, obj: str, goal: GoalAtom, a: Articulation, g: _Drawer) -> Step:
    """Open a drawer whose handle is too low for the level pinch (the bottom drawer): press
    the closed fingertips down on top of the handle bar and drag it out by friction.

    The bar cannot be held at all down there: level, the hand (21 cm along the finger axis)
    would reach through the table; pointing down, the slot between the bar and the drawer
    front (1.6 cm) is narrower than a finger. Pressed down, though, the fingertips' friction
    on the bar (mu ~1) is well above the drawer's damping at a moderate pull. The fingers
    lean toward the cabinet, like `close_drawer`, so the hand's back edge stays out of the
    face of the drawer above; the finger axis lies along the bar."""
    lean = unit(DOWN * np.cos(DRAG_TILT) - g.pull * np.sin(DRAG_TILT))
    # The eef where the fingertips (FINGERTIP_BELOW along the pointing direction) rest on the
    # bar's top, a little out from its middle (the hand's back edge clears the face above).
    tip = np.array([*(g.handle + g.pull * DRAG_OUT)[:2], g.bar_top])
    contact = tip - lean * FINGERTIP_BELOW
    rel = s.eef_pos - contact
    ahead, lateral, dz = rel @ g.pull, rel @ g.side, rel[2]
    if s.facts.get(str(goal), False):
        return _rise(s, g.bar_top + CLEARANCE + HAND_ABOVE_EEF)
    if abs(lateral) < 0.02 and -DRAG_PRESS - 0.012 < dz < 0.004 and -0.012 < ahead < 0.012 + DRAG_SLACK:
        # On the bar, pressing it: drag out, pressing down. The window reaches ahead by what a
        # chunk moves the gripper: the policy's extrapolation leaves the drawer behind.
        remaining = max(OPEN_TO - openness(a), 0.0) + 0.01
        target = s.eef_pos + g.pull * remaining - g.side * lateral
        target[2] = contact[2] - DRAG_PRESS  # pressing: the bar stops the fingers, the controller pushes
        return Step(act(s, target, CLOSE, g.side, lean, cap=DRAG_SPEED))
    if abs(lateral) < 0.012 and abs(ahead) < 0.006 and 0.0 <= dz < DRAG_OVER + 0.012:
        return Step(act(s, contact + DOWN * DRAG_PRESS, CLOSE, g.side, lean, cap=PUSH_SPEED))  # press onto it
    # The bar straight below the next drawer's handle: get over it from the front, just above
    # its top (from above, the fingers would land on the handle of the drawer above).
    over = contact + UP * DRAG_OVER
    if abs(lateral) < 0.012 and 0.0 < ahead < 0.09 and -0.012 < s.eef_pos[2] - over[2] < 0.012 and misalign(s, g.side) < YAW_TOL:
        return Step(act(s, over, CLOSE, g.side, lean, cap=DRAG_SPEED))  # in over the bar, slowly
    ready = over + g.pull * 0.06
    return Step(_approach(s, ready, CLOSE, g.side, lean, a, g.bar_top, _owner(s, obj)))


def _aabb(b) -> Box:
    """A body's world-aligned bounding box as a `Box`."""
    return Box(center=(b.lo + b.hi) / 2, xmat=np.eye(3), half=(b.hi - b.lo) / 2)


def in_sweep(s: SceneState, region: str, movers: tuple[str, ...]) -> str | None:
    """Of the objects to be picked later, one that would end up under the drawer once it is
    open (in the open drawer's footprint, lower than its bottom), where no grasp reaches it:
    the hand is 12 cm tall and would have to come down through the drawer."""
    joints = [s.articulations[n] for n in s.joints_of.get(region, ())]
    a = next((j for j in joints if j.kind == "slide"), None)
    if a is None or openness(a) > SWEEP_CHECK_UNTIL:
        return None
    g = _drawer(a)
    swept_to = _extent(_aabb(a.part), g.pull) + OPEN_TO - openness(a)  # the drawer's front, once open
    for name in movers:
        b = s.bodies.get(name)
        if b is None or b.hi[2] > a.part.lo[2]:
            continue
        across = (b.center - g.handle) @ g.side
        half_side = _extent(_aabb(a.part), g.side) - float(g.handle @ g.side)
        if abs(across) > half_side + float(np.abs(b.hi - b.lo)[:2] @ np.abs(g.side[:2])) / 2:
            continue
        if -_extent(_aabb(b), -g.pull) < swept_to:
            return name  # its back edge is inside the sweep
    return None


def push_clear(s: SceneState, region: str, name: str) -> Step:
    """Push ``name`` out of the drawer's sweep, along the pull, before opening it: closed
    fingers low against its back (the side facing the cabinet), the hand above its rim."""
    a = joint_of(s, region, want_open=True)
    g = _drawer(a)
    b = s.bodies[name]
    swept_to = _extent(_aabb(a.part), g.pull) + OPEN_TO - openness(a)
    back = -_extent(_aabb(b), -g.pull)  # its edge nearest the cabinet, along the pull
    need = swept_to + SWEEP_MARGIN - back
    lateral = float((b.center - g.handle) @ g.side)
    z = max(b.lo[2] + 0.35 * b.size[2], s.table_z + FINGERTIP_BELOW + 0.004)
    contact = np.array([*(g.handle[:2] + g.side[:2] * lateral), z])
    contact = contact + g.pull * (back - FINGER_HALF - float(contact @ g.pull))  # fingers touching its back
    rel = s.eef_pos - contact
    ahead, side = float(rel @ g.pull), float(rel @ g.side)
    if abs(side) < 0.02 and abs(rel[2]) < 0.015 and -0.02 < ahead < 0.03 + PUSH_SLACK:
        target = s.eef_pos + g.pull * (need + 0.005)
        target[2] = z
        return Step(act(s, target, CLOSE, g.side, cap=PUSH_SPEED))
    ready = contact - g.pull * 0.02
    if np.linalg.norm((ready - s.eef_pos)[:2]) < 0.025 and misalign(s, g.side) < YAW_TOL:
        # Over the spot behind it: straight down, correcting sideways drift on the way
        # (nothing but the object itself is near, and the hand stays behind its rim).
        return Step(act(s, ready, CLOSE, g.side))
    hover = np.array([*ready[:2], b.hi[2] + 0.05])
    return Step(_approach(s, hover, CLOSE, g.side, DOWN, a, b.hi[2], _owner(s, region)))


# ---- doors -------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Door:
    a: Articulation
    along: np.ndarray  # horizontal unit vector from the hinge along the door to its free edge
    push: np.ndarray  # horizontal unit normal of the door face that closing pushes on
    face: float  # offset of that face from the hinge along `push`
    inner: float  # offset of the other face from the hinge along `-push`
    handle: np.ndarray  # centre of the handle
    handle_top: float  # top of the handle
    radius: float  # the handle's distance from the hinge
    top: float  # top edge of the door

    def turned(self, v: np.ndarray, toward_closed: float) -> np.ndarray:
        """``v`` as it would be with the door turned ``toward_closed`` radians further shut."""
        return _rotate(v, self.a.axis, -open_sign(self.a) * toward_closed)

    def point(self, radius: float, offset: float, z: float, toward_closed: float = 0.0) -> np.ndarray:
        """World point ``radius`` along the door and ``offset`` off its pushed face's side."""
        along, push = self.turned(self.along, toward_closed), self.turned(self.push, toward_closed)
        p = self.a.anchor + along * radius + push * offset
        return np.array([p[0], p[1], z])


def _door(a: Articulation) -> _Door:
    plate = max(a.geoms, key=lambda g: float(np.prod(g.half)))  # the door leaf
    out = flat(plate.center - a.anchor)
    along = max((flat(plate.xmat[:, i]) for i in range(3)), key=lambda v: abs(v @ out))
    along = unit(along if along @ out > 0 else -along)
    # Closing turns the door by -open_sign about the axis: its face moves along `closing`.
    closing = unit(flat(np.cross(a.axis, along))) * -open_sign(a)
    push = -closing
    dist = [np.linalg.norm(flat(g.center - a.anchor)) for g in a.geoms]
    far = max(d for g, d in zip(a.geoms, dist) if g is not plate)
    grip = [g for g, d in zip(a.geoms, dist) if g is not plate and d > far - 0.03]
    handle = np.mean([g.center for g in grip], axis=0)
    return _Door(a=a, along=along, push=push,
                 face=_extent(plate, push) - float(a.anchor @ push),
                 inner=_extent(plate, -push) + float(a.anchor @ push),
                 handle=handle, handle_top=max(float(g.hi[2]) for g in grip),
                 radius=float(np.linalg.norm(flat(handle - a.anchor))), top=float(plate.hi[2]))


@dataclass(frozen=True)
class Opening:
    """The doorway a hinged door closes (a microwave's front), in the closed door's frame.

    Depth is measured from the closed door's plane into the fixture; lateral offsets from the
    hinge along the closed door. Everything comes from the door's geometry, so the same code
    serves any fixture with a vertical-hinged door and any side it opens on."""

    door: _Door
    out: np.ndarray  # horizontal unit normal of the closed door, pointing out of the fixture
    along: np.ndarray  # horizontal unit vector from the hinge along the closed door
    leaf: float  # the door's length from the hinge: the doorway is no wider than this
    bottom: float  # the door leaf's lower and upper edges: the doorway's height
    top: float

    def depth(self, p: np.ndarray) -> float:
        """How far ``p`` lies inside the closed door's plane (negative: in front of it)."""
        return float((self.door.a.anchor - p) @ self.out)

    def lateral(self, p: np.ndarray) -> float:
        return float((p - self.door.a.anchor) @ self.along)

    def point(self, lateral: float, depth: float, z: float) -> np.ndarray:
        p = self.door.a.anchor + self.along * lateral - self.out * depth
        return np.array([p[0], p[1], z])


def opening(s: SceneState, fixture: str) -> Opening | None:
    """The doorway of ``fixture`` (or of the fixture a region belongs to) if it has a door on
    a vertical hinge; None otherwise (drawers, the stove's knob, open containers)."""
    owner = _owner(s, fixture)
    names = tuple(s.joints_of.get(fixture, ())) + tuple(s.joints_of.get(owner, ()))
    for a in (s.articulations[n] for n in dict.fromkeys(names)):
        if a.kind != "hinge" or abs(a.axis[2]) < 0.9 or not a.geoms:
            continue
        plate = max(a.geoms, key=lambda g: float(np.prod(g.half)))
        if plate.hi[2] - plate.lo[2] < 0.05 or len(a.geoms) < 2:  # a knob, not a door
            continue
        d = _door(a)
        shut = openness(a)
        leaf = max(_extent(g, d.along) for g in a.geoms) - float(a.anchor @ d.along)
        return Opening(door=d, out=d.turned(d.push, shut), along=d.turned(d.along, shut), leaf=leaf,
                       bottom=float(plate.lo[2]), top=float(plate.hi[2]))
    return None


def _box_corners(b) -> np.ndarray:
    return np.array([[x, y, z] for x in (b.lo[0], b.hi[0]) for y in (b.lo[1], b.hi[1]) for z in (b.lo[2], b.hi[2])])


def protrusion(o: Opening, b) -> float:
    """How far the body's box sticks out of the doorway past the closed door's plane."""
    return float(max(-o.depth(c) for c in _box_corners(b)))


def _sticking_out(s: SceneState, o: Opening, fixture: str) -> str | None:
    """An object put into the fixture (its origin inside the doorway) that the closing door
    would hit: it still reaches out past the door's plane."""
    worst, name = -PUSH_IN_MARGIN / 2, None
    for n, b in s.bodies.items():
        if n == fixture or o.depth(b.pos) <= 0 or not 0 < o.lateral(b.pos) < o.leaf:
            continue
        if not o.bottom - 0.03 < b.pos[2] < o.top:
            continue
        if protrusion(o, b) > worst:
            worst, name = protrusion(o, b), n
    return name


def _push_in(s: SceneState, o: Opening, name: str, fixture: str) -> Step:
    """Push an object deeper into the fixture until nothing of it sticks out of the doorway.

    Closed fingers press on the object's outermost part, a little below its middle, across
    the doorway, leaning into the fixture (like `close_drawer`): straight down, the hand's
    upper part (it is 8 cm thick, and 10 cm tall above the fingers) would run into the
    doorway's top edge before the fingers are past the door's plane."""
    b = s.bodies[name]
    out = protrusion(o, b)
    lateral = o.lateral(b.center)
    z = b.lo[2] + PUSH_IN_HEIGHT * b.size[2]
    contact = o.point(lateral, -(out + FINGER_HALF), z)  # eef touching the outermost part
    lean = unit(DOWN * np.cos(DRAWER_TILT) - o.out * np.sin(DRAWER_TILT))
    rel = s.eef_pos - contact
    ahead, across = float(rel @ o.out), float(rel @ o.along)
    push = out + PUSH_IN_MARGIN
    if abs(across) < 0.02 and abs(rel[2]) < 0.015 and -push - 0.02 < ahead < 0.05:
        return Step(act(s, contact - o.out * push, CLOSE, o.along, lean, cap=PUSH_SPEED))
    ready = contact + o.out * 0.03
    return Step(_approach(s, ready, CLOSE, o.along, lean, o.door.a, b.hi[2], fixture))


def close_door(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    """Push the door shut along its arc with closed fingers on its face, near its top edge
    (the hand passes just above the door), then back away. Something put in that still
    sticks out of the doorway (a mug's handle) is pushed in first."""
    d = _door(joint_of(s, obj, want_open=False))
    a = d.a
    rel = s.eef_pos - a.anchor
    radial, off = rel @ d.along, rel @ d.push - d.face  # along the door; out from its face
    if s.facts.get(str(goal), False):
        return _back_off(s, d.push, off, FINGER_HALF + CLEARANCE)
    o = opening(s, obj)
    stuck = _sticking_out(s, o, _owner(s, obj)) if o is not None and openness(a) > 0.3 else None
    if stuck is not None:
        return _push_in(s, o, stuck, _owner(s, obj))
    if o is not None and o.depth(s.eef_pos) > -0.06 and s.eef_pos[2] < o.top - 0.05 and 0 < o.lateral(s.eef_pos) < o.leaf:
        # Just pushed something in: straight back out of the doorway, low, straightening up
        # (rising there, leaning, runs the hand into the doorway's top edge).
        return Step(act(s, s.eef_pos + o.out * (0.07 + o.depth(s.eef_pos)), CLOSE))
    z = d.top - HAND_ABOVE_EEF + 0.015  # hand just above the top edge, fingers on the face
    reach = d.radius - 0.07  # push point: well out along the door, clear of the handle
    lead = min(DOOR_LEAD, openness(a) + 0.05)  # end pressing just past closed
    pushing = abs(radial - reach) < 0.04 and abs(s.eef_pos[2] - z) < 0.012 and -0.06 < off < FINGER_HALF + 0.05
    if pushing:
        target = d.point(reach, d.face + FINGER_HALF, z, toward_closed=lead)
        return Step(act(s, target, CLOSE, d.turned(d.along, lead), cap=PUSH_SPEED))
    inside = _inside(s, d, _owner(s, obj))
    if inside > 0:  # still in the cabinet (just put something in it): straight out first
        out = d.turned(d.push, openness(a))  # the closed door's outward normal
        return Step(act(s, s.eef_pos + out * (inside + 0.05), _keep_gripper(s)))
    ready = d.point(reach, d.face + FINGER_HALF + 0.03, z)
    return Step(_approach(s, ready, CLOSE, d.along, DOWN, a, d.top, _owner(s, obj)))


def open_door(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    """Pull the door open by its handle as far as the arm comfortably reaches, then let go
    and push the rest of the way from the door's inner face; back away once it is open."""
    d = _door(joint_of(s, obj, want_open=True))
    if s.facts.get(str(goal), False):
        grip = _handle_grip(d)
        if s.gripper_width < OPEN_WIDTH and np.linalg.norm(s.eef_pos - grip) < 0.03:
            return Step(_still(s, OPEN))  # let go of the handle first
        side = d.push if (s.eef_pos - d.a.anchor) @ d.push > 0 else -d.push  # the side the gripper is on
        face = d.face if side @ d.push > 0 else d.inner
        return _back_off(s, side, float((s.eef_pos - d.a.anchor) @ side), face + 0.04 + CLEARANCE)
    if openness(d.a) < DOOR_PULL_TO:
        return _pull_handle(s, d, obj)
    return _push_open(s, d, obj)


def _handle_grip(d: _Door) -> np.ndarray:
    """Where the eef pinches the handle: at the handle's radius, just out from its axis (so
    the hand, right above the fingers, clears the door's face), with the pads on the handle's
    top end and its post (the hand cannot go lower: it would sit on the handle)."""
    out = float((d.handle - d.a.anchor) @ d.push) + DOOR_GRIP_OUT
    return d.point(d.radius, out, d.handle_top - HAND_ABOVE_EEF + 0.01)


def _pull_handle(s: SceneState, d: _Door, obj: str) -> Step:
    """Pinch the handle (fingers either side of it along the door) and pull it round the
    hinge, turning the wrist with the door."""
    a = d.a
    rel = flat(s.eef_pos - a.anchor)
    grip = _handle_grip(d)
    out = float((grip - a.anchor) @ d.push)
    # Hold the side of the handle that leaves the wrist room to turn with the door.
    swing = -open_sign(a) * float(a.axis[2]) * (DOOR_PULL_TO - openness(a))  # yaw still to come
    finger = wrist_side(s, d.along, then=swing)
    # Where the eef is around the hinge, relative to the grip point: the door moves with a
    # held handle, and the policy's chunk extrapolation moves only the gripper, so holding is
    # judged by radius and by angle ahead (in the opening direction) of the grip.
    radius = float(np.hypot(d.radius, out))
    ahead = float(np.arctan2(rel @ d.push, rel @ d.along) - np.arctan2(out, d.radius))
    on_arc = abs(np.linalg.norm(rel) - radius) < 0.03 and abs(s.eef_pos[2] - grip[2]) < 0.03
    if on_arc and -0.1 < ahead < DOOR_LEAD + 0.15 and 0.012 < s.gripper_width < 0.05:
        target = d.point(d.radius, out, grip[2], toward_closed=-DOOR_LEAD)
        return Step(act(s, target, CLOSE, d.turned(finger, -DOOR_LEAD), cap=PUSH_SPEED, signed=True))
    err = grip - s.eef_pos
    if s.gripper_width < OPEN_WIDTH:
        if np.linalg.norm(err) < 0.012 and s.gripper_width > 0.012:
            return Step(act(s, grip, CLOSE, finger, signed=True))  # still closing on it
        return Step(act(s, s.eef_pos + d.push * 0.01, OPEN, finger, signed=True))  # open, backing out
    aligned = abs(yaw_toward(s, finger, signed=True)) < 0.1
    if np.linalg.norm(err) < 0.006 and aligned:
        return Step(act(s, grip, CLOSE, finger, signed=True))  # there: pinch
    offset = rel @ d.push - out  # how far out in front of the grip point
    if abs(float(rel @ d.along) - d.radius) < 0.01 and abs(err[2]) < 0.01 and -0.01 < offset < 0.08 and aligned:
        return Step(act(s, grip, OPEN, finger, cap=PUSH_SPEED, signed=True))  # straight in
    ready = d.point(d.radius, out + 0.05, grip[2])
    return Step(_approach(s, ready, OPEN, finger, DOWN, a, d.top, _owner(s, obj), signed=True))


def _push_open(s: SceneState, d: _Door, obj: str) -> Step:
    """Push the half-open door further open from its inner face, near the hinge (little
    reach needed), like `close_door` from the other side."""
    a = d.a
    rel = s.eef_pos - a.anchor
    grip = _handle_grip(d)
    if s.gripper_width < OPEN_WIDTH and np.linalg.norm(s.eef_pos - grip) < 0.03:
        return Step(_still(s, OPEN))  # still holding the handle: let go
    out = float((grip - a.anchor) @ d.push)
    round_handle = abs(rel @ d.along - d.radius) < 0.05 and -0.02 < rel @ d.push - out < 0.04
    if round_handle and s.eef_pos[2] < d.handle_top + 0.02:
        # Fingers round the handle's top: straight up off it first (backing out, away from
        # the hinge, would take the arm out of reach).
        return Step(act(s, np.array([*s.eef_pos[:2], d.handle_top + 0.02]), OPEN))
    z = d.top - HAND_ABOVE_EEF + 0.015  # hand just above the door's top edge, fingers on its face
    reach = DOOR_INNER_REACH * d.radius
    radial, off = rel @ d.along, rel @ -d.push - d.inner  # along the door; in from its inner face
    if abs(radial - reach) < 0.04 and abs(s.eef_pos[2] - z) < 0.012 and -0.06 < off < FINGER_HALF + 0.05:
        lead = min(DOOR_LEAD, DOOR_OPEN_TO - openness(a) + 0.05)
        target = d.point(reach, -(d.inner + FINGER_HALF), z, toward_closed=-lead)
        return Step(act(s, target, CLOSE, d.turned(d.along, -lead), cap=PUSH_SPEED))
    ready = d.point(reach, -(d.inner + FINGER_HALF + 0.03), z)
    # Over the door's top edge only just: the door is far out, where the arm has little reach
    # left to go higher (stretched, its elbow locks straight and it stops following).
    return Step(_approach(s, ready, CLOSE, d.along, DOWN, a, d.top - 0.025, _owner(s, obj)))


def _inside(s: SceneState, d: _Door, fixture: str) -> float:
    """How deep the eef is behind the closed door's plane, within the fixture's box (0 if
    it is not in there)."""
    out = d.turned(d.push, openness(d.a))
    depth = float((d.a.anchor - s.eef_pos) @ out)
    box = s.bodies.get(fixture)
    if box is None or depth <= 0 or s.eef_pos[2] > box.hi[2]:
        return 0.0
    within = np.all(s.eef_pos[:2] > box.lo[:2]) and np.all(s.eef_pos[:2] < box.hi[:2])
    return depth if within else 0.0


# ---- knobs -------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Knob:
    a: Articulation
    centre: np.ndarray  # on the axis, at the height to grip the ridge
    across: np.ndarray  # horizontal unit vector across the ridge (the finger axis to grip it)
    top: float  # top of the ridge


def _knob(a: Articulation) -> _Knob:
    top = max(float(g.hi[2]) for g in a.geoms)
    ridge = [g for g in a.geoms if g.hi[2] > top - 0.012]  # the raised grip across the knob
    # The ridge's long direction: principal axis of its boxes' corners, seen from above.
    corners = np.concatenate([_corners(g) for g in ridge])
    xy = corners[:, :2] - corners[:, :2].mean(0)
    length = np.linalg.eigh(xy.T @ xy)[1][:, -1]
    across = np.array([-length[1], length[0], 0.0])
    centre = np.array([a.anchor[0], a.anchor[1], top - KNOB_GRIP_DEPTH])
    return _Knob(a=a, centre=centre, across=across, top=top)


def turn_knob(s: SceneState, obj: str, goal: GoalAtom, on: bool) -> Step:
    """Grip the knob's ridge across, twist the wrist until the knob is on (or off), let go,
    and rise clear."""
    k = _knob(joint_of(s, obj, want_open=on))
    err = k.centre - s.eef_pos
    near = np.linalg.norm(err[:2]) < 0.012 and abs(err[2]) < 0.015
    turn = open_sign(k.a) * (1.0 if on else -1.0)  # which way qpos has to go
    if s.facts.get(str(goal), False):
        if near and s.gripper_width < OPEN_WIDTH:
            # Let go of the ridge before moving; but a knob let go while still pressed into
            # its stop springs back past "off": first hold still until it has eased off.
            if s.gripper_width < 0.05 and not on and _pressed_into_stop(k.a):
                return Step(np.array([0, 0, 0, 0, 0, 0, CLOSE], dtype=np.float64))  # keep the controller's goal
            return Step(_still(s, OPEN))
        return _rise(s, k.top + CLEARANCE)
    # Hold the ridge the way round that leaves the wrist room for the whole twist: a 1.5 rad
    # twist started from the wrong side runs the wrist into its stop.
    twist = turn * (KNOB_ON_AT + 0.1 - openness(k.a) if on else openness(k.a))
    grip = wrist_side(s, k.across, then=twist * float(k.a.axis[2]))
    if near and misalign(s, k.across) < 0.5 and s.gripper_width > 0.012:
        if s.gripper_width >= 0.05:  # closing on the ridge, still centring
            return Step(act(s, k.centre, CLOSE))
        # Holding the ridge: keep the wrist a full lead ahead of the knob until the sub-goal
        # holds (the grip gives by up to ~0.2 rad, so a lead that shrank near the target
        # would stall short of it); "off" ends pressed against the joint's stop.
        return Step(act(s, k.centre, CLOSE, _rotate(grip, k.a.axis, KNOB_LEAD * turn), signed=True))
    if s.gripper_width < OPEN_WIDTH:  # closed on nothing, or slipped off: open, moving up a little
        return Step(act(s, s.eef_pos + UP * 0.01, OPEN))
    hover = np.array([*k.centre[:2], k.top + 0.05])
    if np.linalg.norm(err[:2]) < 0.01 and abs(yaw_toward(s, grip, signed=True)) < 0.1:
        if near:
            return Step(act(s, k.centre, CLOSE))  # there: grip
        return Step(act(s, k.centre, OPEN, grip, signed=True))  # straight down onto it
    if s.eef_pos[2] < hover[2] - 0.02 and np.linalg.norm(err[:2]) > 0.02:
        return Step(act(s, np.array([*s.eef_pos[:2], hover[2]]), OPEN, grip, signed=True))  # up first
    return Step(act(s, hover, OPEN, grip, signed=True))


def _pressed_into_stop(a: Articulation) -> bool:
    """Whether the joint sits measurably past its closed-side limit (MuJoCo's limits are soft)."""
    stop = a.range[0] if open_sign(a) > 0 else a.range[1]
    return (stop - a.qpos) * open_sign(a) > 0.0005


def turn_on(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    return turn_knob(s, obj, goal, on=True)


def turn_off(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    return turn_knob(s, obj, goal, on=False)


# ---- dispatch ----------------------------------------------------------------------------
def open_(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    """Open a drawer (region of a cabinet) or a door (microwave)."""
    a = joint_of(s, obj, want_open=True)
    if a.kind == "slide":
        return open_drawer(s, obj, goal)
    return open_door(s, obj, goal)


def close(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    """Close a drawer (region of a cabinet) or a door (microwave)."""
    a = joint_of(s, obj, want_open=False)
    if a.kind == "slide":
        return close_drawer(s, obj, goal)
    return close_door(s, obj, goal)


ARTICULATED_SKILLS: dict = {"open": open_, "close": close, "turn_on": turn_on, "turn_off": turn_off}
