"""Motion primitives for articulated fixtures: drawers, the microwave door, the stove knob.

Each maps (scene, LIBERO name, sub-goal atom) to a `skills.Step`, reactively, like
`skills.pick`/`skills.place`: the action is a function of the current `SceneState` alone, so a
skill resumes after any snapshot restore, and a slipped push or grasp is retried by itself
(the rules see the gripper out of place and bring it back).

Geometry comes from `SceneState.articulations` (joint axis and anchor, the moving part's
collision boxes), never from per-task constants:

* drawer (slide joint): the handle is the part's geometry sticking out furthest along the
  pull direction. Close: closed fingers push the handle in, the gripper tilted toward the
  cabinet so the forearm stays clear of the cabinet's top.
* door (hinge joint, e.g. microwave_1): the handle is the part's geometry furthest from the
  hinge. Close: closed fingers push the outer face of the door along its arc, high up so the
  wide hand passes over the door's top edge. Open: grasp the handle at its top and pull it
  along the arc, turning the wrist with the door.
* knob (a hinge whose handle sits on its axis, flat_stove_1): grasp the ridge across, twist
  the wrist, let go.

Every skill ends with the gripper backed away from the fixture and pointing straight down
again, so the next skill (which only steers yaw) starts clean.

LIBERO's convention: a fixture is closed / off near ``qpos == 0`` and opens toward the far end
of the joint range. Whether the sub-goal holds is read from ``scene.facts[str(goal)]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.policies.expert.skills import CLOSE, OPEN, OPEN_WIDTH, POS_GAIN, YAW_GAIN, Step, _finger_yaw
from seal.sim.goals import GoalAtom
from seal.sim.scene import Articulation, Box, SceneState

FINGER_HALF = 0.012  # half thickness of the closed fingers across the finger axis (+ margin)
HAND_ABOVE_EEF = 0.026  # the hand's underside sits this far above the end-effector site
CLEARANCE = 0.06  # how far the gripper backs away from a fixture before a skill is done
PUSH_SPEED = 0.6  # action cap while pushing or pulling (~7 mm/step): firm, not violent
TILT_GAIN = 1.5  # rotation action per radian of roll/pitch error
YAW_TOL = 0.15  # finger-axis alignment needed before going down next to a fixture
UPRIGHT_TOL = 0.1  # radians of tilt still counted as pointing straight down
DRAWER_TILT = 0.5  # radians the fingers lean toward a drawer while pushing it

UP = np.array([0.0, 0.0, 1.0])
DOWN = -UP


# ---- geometry ----------------------------------------------------------------------------
def _unit(v: np.ndarray) -> np.ndarray:
    return v / (np.linalg.norm(v) + 1e-12)


def _flat(v: np.ndarray) -> np.ndarray:
    """Horizontal part of a vector."""
    return np.array([v[0], v[1], 0.0])


def _extent(box: Box, direction: np.ndarray) -> float:
    """How far the box reaches along ``direction`` (max of corner · direction)."""
    return float(box.center @ direction + np.abs(box.xmat.T @ direction) @ box.half)


_SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)


def _corners(box: Box) -> np.ndarray:
    """The box's 8 corners, world frame."""
    return box.center + (_SIGNS * box.half) @ box.xmat.T


def _joint(s: SceneState, obj: str, want_open: bool) -> Articulation:
    """The joint behind a fixture or region; of several (a whole cabinet), one not yet there."""
    names = s.joints_of.get(obj, ())
    if not names:
        raise KeyError(f"{obj!r} has no articulated joint; known: {sorted(s.joints_of)}")
    joints = [s.articulations[n] for n in names]
    return min(joints, key=lambda a: _openness(a) if want_open else -_openness(a))


def _open_sign(a: Articulation) -> float:
    """+1 if opening increases qpos (the range's far end from 0 is positive), else -1."""
    lo, hi = a.range
    return 1.0 if abs(hi) >= abs(lo) else -1.0


def _openness(a: Articulation) -> float:
    """How far from closed (metres for a slide, radians for a hinge); 0 when closed."""
    return a.qpos * _open_sign(a)


def _rotate_z(v: np.ndarray, angle: float) -> np.ndarray:
    c, si = np.cos(angle), np.sin(angle)
    return np.array([c * v[0] - si * v[1], si * v[0] + c * v[1], v[2]])


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


# ---- actions -----------------------------------------------------------------------------
def _tilt(s: SceneState) -> float:
    """Angle between the fingers' pointing direction and straight down."""
    return float(np.arccos(np.clip(-s.eef_xmat[2, 2], -1.0, 1.0)))


def _act(s: SceneState, goal: np.ndarray, gripper: float, finger_dir: np.ndarray | None = None,
         point: np.ndarray = DOWN, cap: float = 1.0, signed: bool = False) -> np.ndarray:
    """Move the eef toward ``goal`` (each axis at most ``cap``), turn the fingers to point
    along ``point`` and the finger axis to lie along ``finger_dir`` (either sign unless
    ``signed``; None keeps the yaw).

    Roll and pitch are steered from the eef frame's pointing axis; yaw from the finger axis,
    which the policy's chunk extrapolation keeps up to date."""
    delta = np.clip(POS_GAIN * (goal - s.eef_pos), -1.0, 1.0)
    peak = np.abs(delta).max()
    if peak > cap:
        delta *= cap / peak
    rot = TILT_GAIN * np.cross(s.eef_xmat[:, 2], _unit(point))  # world-frame axis * sin(angle)
    rot[2] = 0.0
    if finger_dir is not None:
        rot[2] = YAW_GAIN * _yaw_err(s, finger_dir, signed)
    return np.array([*delta, *np.clip(rot, -1.0, 1.0), gripper])


def _yaw_err(s: SceneState, finger_dir: np.ndarray, signed: bool = False) -> float:
    """Yaw that turns the finger axis onto ``finger_dir`` (``signed``: pad to pad exactly;
    else either way round, whichever keeps the wrist nearer the middle of its range).

    Angles are measured from WRIST_MID_YAW and never wrap through the opposite direction,
    where the wrist's last joint hits its stops: the wrist may turn the long way round
    rather than into a stop."""
    now = _wrist(_finger_yaw(s))
    target = _wrist(_yaw_of(finger_dir if signed else _wrist_side(s, finger_dir)))
    return target - now


def _wrist_side(s: SceneState, finger_dir: np.ndarray, then: float = 0.0) -> np.ndarray:
    """Of ``finger_dir`` and its opposite (the same grip for a symmetric gripper), the one
    that leaves the wrist nearest the middle of its range after a further ``then`` radians
    of yaw; ties go to the nearer one, so the choice does not flip back and forth."""
    now = _wrist(_finger_yaw(s))

    def cost(d: np.ndarray) -> float:
        t = _wrist(_yaw_of(d))
        return abs(t + then) + 0.5 * abs(t - now)

    return min((finger_dir, -finger_dir), key=cost)


def _misalign(s: SceneState, finger_dir: np.ndarray) -> float:
    """Angle between the finger axis and ``finger_dir``, either way round (0..pi/2)."""
    d = (_yaw_of(finger_dir) - _finger_yaw(s)) % np.pi
    return float(min(d, np.pi - d))


WRIST_MID_YAW = 2.6  # finger-axis yaw with the wrist's last joint mid-range (measured: q7 = 0)


def _wrist(yaw: float) -> float:
    """A finger-axis yaw as an offset from the wrist's mid-range, in [-pi, pi)."""
    return (yaw - WRIST_MID_YAW + np.pi) % (2 * np.pi) - np.pi


def _yaw_of(v: np.ndarray) -> float:
    return float(np.arctan2(v[1], v[0]))


def _still(s: SceneState, gripper: float) -> np.ndarray:
    """Stay put (straightening up) while the fingers open or close."""
    return _act(s, s.eef_pos, gripper)


def _keep_gripper(s: SceneState) -> float:
    """Closed stays closed, open stays open (no pointless finger motion while retreating)."""
    return CLOSE if s.gripper_width < 0.04 else OPEN


# ---- drawers -----------------------------------------------------------------------------
@dataclass(frozen=True)
class _Drawer:
    pull: np.ndarray  # horizontal unit vector the drawer slides along when opening
    side: np.ndarray  # horizontal unit vector across the drawer front
    handle: np.ndarray  # centre of the handle bar
    front: float  # outermost reach of the handle along `pull`, from the handle centre
    top: float  # top of the drawer


def _drawer(a: Articulation) -> _Drawer:
    pull = _unit(_flat(a.axis * _open_sign(a)))
    side = np.array([-pull[1], pull[0], 0.0])
    reach = np.array([_extent(g, pull) for g in a.geoms])
    outer = reach.max()
    bar = [g for g, r in zip(a.geoms, reach) if r > outer - 0.004]  # the handle bar
    lo = np.min([g.lo for g in bar], axis=0)
    hi = np.max([g.hi for g in bar], axis=0)
    handle = (lo + hi) / 2
    return _Drawer(pull=pull, side=side, handle=handle, front=float(outer - handle @ pull), top=float(a.part.hi[2]))


def close_drawer(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    """Push the drawer in with closed fingers on its handle; back away once it is shut.

    The fingers lean toward the cabinet while pushing: with the gripper straight down, the
    forearm runs into the cabinet's top before a low drawer is fully in."""
    a = _joint(s, obj, want_open=False)
    g = _drawer(a)
    rel = s.eef_pos - g.handle
    ahead, lateral = rel @ g.pull, rel @ g.side  # eef offset out from / across the handle
    contact = g.front + FINGER_HALF  # `ahead` at which the fingers touch the bar
    if s.facts.get(str(goal), False):
        return _back_off(s, g.pull, ahead, contact + CLEARANCE)
    lean = _unit(DOWN * np.cos(DRAWER_TILT) - g.pull * np.sin(DRAWER_TILT))
    # Push: level with the handle, in front of it or pressing on it. The target lies where the
    # fingers would be with the drawer shut (+1 cm), so the push ends against the stop.
    remaining = _openness(a) + 0.01
    if abs(lateral) < 0.02 and abs(rel[2]) < 0.015 and contact - remaining - 0.02 < ahead < contact + 0.05:
        target = g.handle + g.pull * (contact - remaining)
        return Step(_act(s, target, CLOSE, g.side, lean, cap=PUSH_SPEED))
    ready = g.handle + g.pull * (contact + 0.03)
    return Step(_approach(s, ready, CLOSE, g.side, lean, _drawer_travel(s, obj, a, g)))


def _drawer_travel(s: SceneState, obj: str, a: Articulation, g: _Drawer) -> float:
    """Height to move above the drawer at: over its top and whatever sits in it."""
    return _travel_height(s, a.part.lo, a.part.hi, max(g.top, g.handle[2] + 0.03), skip=_owner(s, obj))


def _approach(s: SceneState, ready: np.ndarray, gripper: float, finger_dir: np.ndarray, point: np.ndarray,
              travel_z: float) -> np.ndarray:
    """Get to ``ready`` (next to a handle) without sweeping through anything: up to
    ``travel_z``, across, then straight down once turned the right way. Heights are absolute
    targets, so the arm's sag during fast moves is corrected rather than accumulated."""
    err = ready - s.eef_pos
    if np.linalg.norm(err[:2]) < 0.015 and _misalign(s, finger_dir) < YAW_TOL:
        return _act(s, ready, gripper, finger_dir, point)  # straight down (or up) onto it
    high = max(travel_z, ready[2] + 0.04)
    if s.eef_pos[2] < high - 0.02:
        return _act(s, np.array([*s.eef_pos[:2], high]), gripper, finger_dir, point)  # up first
    return _act(s, np.array([ready[0], ready[1], high]), gripper, finger_dir, point)


def _back_off(s: SceneState, away: np.ndarray, ahead: float, far: float) -> Step:
    """Retreat along ``away`` until ``ahead`` (the eef's offset that way) reaches ``far``,
    straightening the gripper to point down, then report done."""
    if ahead > far - 0.01 and _tilt(s) < UPRIGHT_TOL:
        return Step(_still(s, _keep_gripper(s)), done=True)
    target = s.eef_pos + away * max(far - ahead, 0.0) + UP * 0.01
    return Step(_act(s, target, _keep_gripper(s)))


# ---- doors -------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Door:
    a: Articulation
    along: np.ndarray  # horizontal unit vector from the hinge along the door to its free edge
    push: np.ndarray  # horizontal unit normal of the door face that closing pushes on
    face: float  # offset of that face from the hinge along `push`
    handle: np.ndarray  # centre of the handle
    radius: float  # the handle's distance from the hinge
    top: float  # top edge of the door

    def turned(self, v: np.ndarray, toward_closed: float) -> np.ndarray:
        """``v`` as it would be with the door turned ``toward_closed`` radians further shut."""
        return _rotate(v, self.a.axis, -_open_sign(self.a) * toward_closed)

    def point(self, radius: float, offset: float, z: float, toward_closed: float = 0.0) -> np.ndarray:
        """World point ``radius`` along the door and ``offset`` off its pushed face's side."""
        p = self.a.anchor + self.turned(self.along, toward_closed) * radius + self.turned(self.push, toward_closed) * offset
        return np.array([p[0], p[1], z])


def _rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: ``v`` turned by ``angle`` about the unit ``axis``."""
    c, si = np.cos(angle), np.sin(angle)
    return v * c + np.cross(axis, v) * si + axis * (axis @ v) * (1 - c)


def _door(a: Articulation) -> _Door:
    plate = max(a.geoms, key=lambda g: float(np.prod(g.half)))  # the door leaf
    out = _flat(plate.center - a.anchor)
    along = max((_flat(plate.xmat[:, i]) for i in range(3)), key=lambda v: abs(v @ out))
    along = _unit(along if along @ out > 0 else -along)
    # Closing turns the door by -open_sign about the axis: its face moves along `closing`.
    closing = _unit(_flat(np.cross(a.axis, along))) * -_open_sign(a)
    push = -closing
    dist = [np.linalg.norm(_flat(g.center - a.anchor)) for g in a.geoms]
    far = max(d for g, d in zip(a.geoms, dist) if g is not plate)
    grip = [g for g, d in zip(a.geoms, dist) if g is not plate and d > far - 0.03]
    handle = np.mean([g.center for g in grip], axis=0)
    return _Door(a=a, along=along, push=push, face=_extent(plate, push) - float(a.anchor @ push),
                 handle=handle, radius=float(np.linalg.norm(_flat(handle - a.anchor))), top=float(plate.hi[2]))


DOOR_LEAD = 0.25  # radians the push target runs ahead of the door while closing it


def close_door(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    """Push the door shut along its arc with closed fingers on its face, near its top edge
    (the hand passes just above the door), then back away."""
    d = _door(_joint(s, obj, want_open=False))
    a = d.a
    rel = s.eef_pos - a.anchor
    radial, off = rel @ d.along, rel @ d.push - d.face  # along the door; out from its face
    if s.facts.get(str(goal), False):
        return _back_off(s, d.push, off, FINGER_HALF + CLEARANCE)
    z = d.top - HAND_ABOVE_EEF + 0.015  # hand just above the top edge, fingers on the face
    reach = d.radius - 0.07  # push point: well out along the door, clear of the handle
    lead = min(DOOR_LEAD, _openness(a) + 0.05)  # end pressing just past closed
    pushing = abs(radial - reach) < 0.04 and abs(s.eef_pos[2] - z) < 0.02 and -0.06 < off < FINGER_HALF + 0.05
    if pushing:
        target = d.point(reach, d.face + FINGER_HALF, z, toward_closed=lead)
        return Step(_act(s, target, CLOSE, d.turned(d.along, lead), cap=PUSH_SPEED))
    inside = _inside(s, d, _owner(s, obj))
    if inside > 0:  # still in the cabinet (just put something in it): straight out first
        out = d.turned(d.push, _openness(a))  # the closed door's outward normal
        return Step(_act(s, s.eef_pos + out * (inside + 0.05), _keep_gripper(s)))
    ready = d.point(reach, d.face + FINGER_HALF + 0.03, z)
    travel = _travel_height(s, a.part.lo, a.part.hi, d.top, skip=_owner(s, obj))
    return Step(_approach(s, ready, CLOSE, d.along, DOWN, travel))


def _inside(s: SceneState, d: _Door, fixture: str) -> float:
    """How deep the eef is behind the closed door's plane, within the fixture's box (0 if
    it is not in there)."""
    out = d.turned(d.push, _openness(d.a))
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


KNOB_GRIP_DEPTH = 0.02  # eef this far below the ridge's top: pads on the ridge, tips above the dial
KNOB_LEAD = 0.4  # radians the wrist runs ahead of the knob while twisting


def turn_knob(s: SceneState, obj: str, goal: GoalAtom, on: bool) -> Step:
    """Grip the knob's ridge across, twist the wrist until the knob is on (or off), let go,
    and rise clear."""
    k = _knob(_joint(s, obj, want_open=on))
    err = k.centre - s.eef_pos
    near = np.linalg.norm(err[:2]) < 0.012 and abs(err[2]) < 0.015
    turn = _open_sign(k.a) * (1.0 if on else -1.0)  # which way qpos has to go
    if s.facts.get(str(goal), False):
        if near and s.gripper_width < OPEN_WIDTH:
            # Let go of the ridge before moving; but a knob let go while still pressed into
            # its stop springs back past "off": first hold still until it has eased off.
            if s.gripper_width < 0.05 and not on and _pressed_into_stop(k.a):
                return Step(np.array([0, 0, 0, 0, 0, 0, CLOSE], dtype=np.float64))  # no rotation: hold the goal
            return Step(_still(s, OPEN))
        return _rise(s, k.top + CLEARANCE)
    # Hold the ridge the way round that leaves the wrist room for the whole twist: a 1.5 rad
    # twist started from the wrong side runs the wrist into its stop.
    twist = turn * (KNOB_ON_AT + 0.1 - _openness(k.a) if on else _openness(k.a))
    grip = _wrist_side(s, k.across, then=twist * float(k.a.axis[2]))
    if near and _misalign(s, k.across) < 0.5 and s.gripper_width > 0.012:
        if s.gripper_width >= 0.05:  # closing on the ridge, still centring
            return Step(_act(s, k.centre, CLOSE))
        # Holding the ridge: keep the wrist a full lead ahead of the knob until the sub-goal
        # holds (the grip gives by up to ~0.2 rad, so a lead that shrank near the target
        # would stall short of it); "off" ends pressed against the joint's stop.
        return Step(_act(s, k.centre, CLOSE, _rotate(grip, k.a.axis, KNOB_LEAD * turn), signed=True))
    if s.gripper_width < OPEN_WIDTH:  # closed on nothing, or slipped off: open, moving up a little
        return Step(_act(s, s.eef_pos + UP * 0.01, OPEN))
    hover = np.array([*k.centre[:2], k.top + 0.05])
    if np.linalg.norm(err[:2]) < 0.01 and abs(_yaw_err(s, grip, signed=True)) < 0.1:
        if near:
            return Step(_act(s, k.centre, CLOSE))  # there: grip
        return Step(_act(s, k.centre, OPEN, grip, signed=True))  # straight down onto it
    if s.eef_pos[2] < hover[2] - 0.02 and np.linalg.norm(err[:2]) > 0.02:
        return Step(_act(s, np.array([*s.eef_pos[:2], hover[2]]), OPEN, grip, signed=True))  # up first
    return Step(_act(s, hover, OPEN, grip, signed=True))


KNOB_ON_AT = 0.5  # LIBERO's stove is on from qpos 0.5
def _pressed_into_stop(a: Articulation) -> bool:
    """Whether the joint sits measurably past its closed-side limit (MuJoCo's limits are soft)."""
    stop = a.range[0] if _open_sign(a) > 0 else a.range[1]
    return (stop - a.qpos) * _open_sign(a) > 0.0005


def _rise(s: SceneState, height: float) -> Step:
    """Go up to ``height`` with the gripper straightening, then report done."""
    if s.eef_pos[2] > height - 0.01 and _tilt(s) < UPRIGHT_TOL:
        return Step(_still(s, _keep_gripper(s)), done=True)
    return Step(_act(s, np.array([*s.eef_pos[:2], max(height, s.eef_pos[2])]), _keep_gripper(s)))


def turn_on(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    return turn_knob(s, obj, goal, on=True)


def turn_off(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    return turn_knob(s, obj, goal, on=False)


# ---- dispatch ----------------------------------------------------------------------------
def close(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    a = _joint(s, obj, want_open=False)
    if a.kind == "slide":
        return close_drawer(s, obj, goal)
    return close_door(s, obj, goal)


ARTICULATED_SKILLS: dict = {"close": close, "turn_on": turn_on, "turn_off": turn_off}
