"""Motion primitives for articulated fixtures: drawers, the microwave door, the stove knob.

Each maps (scene, LIBERO name, sub-goal atom) to a `skills.Step`, reactively, like
`skills.pick`/`skills.place`: the action is a function of the current `SceneState` alone, so a
skill resumes after any snapshot restore, and a slipped push or grasp is retried by itself
(the rules see the gripper out of place and bring it back).

Geometry comes from `SceneState.articulations` (joint axis and anchor, the moving part's
collision boxes), never from per-task constants:

* drawer (slide joint): the handle is the part's geometry sticking out furthest along the
  pull direction. Close: closed fingers push the handle in. Open: straddle the handle bar
  (one finger in the slot behind it) and pull.
* door (hinge joint, e.g. microwave_1): the handle is the part's geometry furthest from the
  hinge. Close: closed fingers push the outer face of the door along its arc, high up so the
  wide hand passes over the door's top edge. Open: grasp the handle at its top and pull it
  along the arc, turning the wrist with the door.
* knob (hinge joint whose handle sits on its axis, e.g. flat_stove_1): grasp the ridge
  across, twist the wrist, let go.

LIBERO's convention: a fixture is closed / off near ``qpos == 0`` and opens toward the far end
of the joint range. Whether the sub-goal holds is read from ``scene.facts[str(goal)]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.policies.expert.skills import CLOSE, OPEN, OPEN_WIDTH, Step, _finger_yaw, _wrap, hold, move
from seal.sim.goals import GoalAtom
from seal.sim.scene import Articulation, Box, SceneState

FINGER_HALF = 0.011  # half thickness of the closed fingers across the finger axis
HAND_ABOVE_EEF = 0.026  # the hand's underside sits this far above the end-effector site
CLEARANCE = 0.06  # how far the gripper backs away from a fixture before a skill is done
PUSH_SPEED = 0.6  # action cap while pushing or pulling (~7 mm/step): firm, not violent
YAW_TOL = 0.15  # finger-axis alignment needed before going down next to a fixture

UP = np.array([0.0, 0.0, 1.0])


# ---- geometry ----------------------------------------------------------------------------
def _unit(v: np.ndarray) -> np.ndarray:
    return v / (np.linalg.norm(v) + 1e-12)


def _flat(v: np.ndarray) -> np.ndarray:
    """Horizontal part of a vector."""
    return np.array([v[0], v[1], 0.0])


def _extent(box: Box, direction: np.ndarray) -> float:
    """How far the box reaches along ``direction`` (max of corner · direction)."""
    return float(box.center @ direction + np.abs(box.xmat.T @ direction) @ box.half)


def _yaw_of(v: np.ndarray) -> float:
    return float(np.arctan2(v[1], v[0]))


def _yaw_err(s: SceneState, finger_dir: np.ndarray) -> float:
    """Yaw (about world z) that brings the finger axis parallel to ``finger_dir``."""
    return _wrap(_yaw_of(finger_dir) - _finger_yaw(s))


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


def _travel_height(s: SceneState, lo: np.ndarray, hi: np.ndarray, floor: float, skip: str = "") -> float:
    """A height to cross the horizontal rectangle lo..hi at: above ``floor`` and above every
    object whose box overlaps it (fixtures other than ``skip`` included)."""
    top = floor
    for name, b in s.bodies.items():
        if name == skip:
            continue
        if b.lo[0] < hi[0] and b.hi[0] > lo[0] and b.lo[1] < hi[1] and b.hi[1] > lo[1]:
            top = max(top, b.hi[2])
    return top + 0.05


# ---- drawers -----------------------------------------------------------------------------
@dataclass(frozen=True)
class _Drawer:
    pull: np.ndarray  # horizontal unit vector the drawer slides along when opening
    side: np.ndarray  # horizontal unit vector across the drawer front
    handle: np.ndarray  # centre of the handle bar
    front: float  # outermost reach of the handle along `pull`, relative to `handle`
    back: float  # how far behind the handle centre the slot behind the bar ends (the face)
    depth: float  # half thickness of the bar along `pull`
    top: float  # top of the drawer


def _drawer(a: Articulation) -> _Drawer:
    pull = _unit(_flat(a.axis * _open_sign(a)))
    side = np.array([-pull[1], pull[0], 0.0])
    reach = np.array([_extent(g, pull) for g in a.geoms])
    outer = reach.max()
    bar = [g for g, r in zip(a.geoms, reach) if r > outer - 0.004]
    lo = np.min([g.lo for g in bar], axis=0)
    hi = np.max([g.hi for g in bar], axis=0)
    handle = (lo + hi) / 2
    depth = float(np.abs(hi - lo) @ np.abs(pull)) / 2
    # The drawer face: the furthest-out geometry that spans the drawer's width (not the posts).
    wide = [r for g, r in zip(a.geoms, reach) if np.abs(g.hi - g.lo) @ np.abs(side) > 0.15 and r < outer - 0.004]
    face = max(wide) if wide else outer - 0.03
    return _Drawer(pull=pull, side=side, handle=handle, front=outer - handle @ pull,
                   back=handle @ pull - face, depth=depth, top=float(a.part.hi[2]))


def close_drawer(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    """Push the drawer in with closed fingers on its handle; back away once it is shut."""
    a = _joint(s, obj, want_open=False)
    g = _drawer(a)
    rel = s.eef_pos - g.handle
    ahead = rel @ g.pull  # how far out in front of the handle centre
    lateral = rel @ g.side
    yaw_err = _yaw_err(s, g.side)  # fingers side by side along the front: a narrow pusher
    contact = g.front + FINGER_HALF  # eef offset along `pull` when the fingers touch the bar
    if s.facts.get(str(goal), False):
        return _back_off(s, g.handle, g.pull, ahead, contact)
    # Push: level with the handle, right in front of it or pressing on it. The target lies
    # where the fingers would be with the drawer shut (+1 cm), so the push ends against the stop.
    remaining = _openness(a) + 0.01
    if abs(lateral) < 0.02 and abs(rel[2]) < 0.015 and contact - remaining - 0.02 < ahead < contact + 0.05:
        goal_pos = g.handle + g.pull * (contact - remaining)
        return Step(_capped(move(s.eef_pos, goal_pos, CLOSE, yaw_err), PUSH_SPEED))
    return Step(_approach(s, g.handle + g.pull * (contact + 0.03), g.pull, ahead, lateral, contact,
                          yaw_err, CLOSE, _drawer_travel(s, obj, a, g)))


def open_drawer(s: SceneState, obj: str, goal: GoalAtom) -> Step:
    """Straddle the handle bar along the pull direction (back finger in the slot behind it),
    close, and pull; let go and back away once the drawer is open."""
    a = _joint(s, obj, want_open=True)
    g = _drawer(a)
    rel = s.eef_pos - g.handle
    ahead = rel @ g.pull
    lateral = rel @ g.side
    yaw_err = _yaw_err(s, g.pull)  # finger axis along the pull: one finger each side of the bar
    # Grip point: the back finger's pad sits in the slot, just behind the bar; the open
    # fingers' pads are OPEN_PAD from the centre, so shift the centre out by the difference.
    slot = (g.depth + g.back) / 2  # middle of the slot behind the bar, from the handle centre
    grip = g.handle + g.pull * (OPEN_PAD - slot)
    if s.facts.get(str(goal), False):
        if s.gripper_width < OPEN_WIDTH and ahead < contact_free(g):
            return Step(hold(OPEN))  # let go of the handle first
        return _back_off(s, g.handle, g.pull, ahead, contact_free(g))
    err = grip - s.eef_pos
    at_grip = np.linalg.norm(err[:2]) < 0.008 and abs(err[2]) < 0.01
    holding = s.gripper_width < 0.05 and abs(rel @ g.pull) < OPEN_PAD and abs(lateral) < 0.03 and abs(rel[2]) < 0.02
    if holding and s.gripper_width > 0.012:
        # Pull straight out along the slide; overshoot the open threshold a little.
        remaining = OPEN_TARGET - _openness(a)
        goal_pos = s.eef_pos + g.pull * max(remaining, 0.0) + _flat(-rel) * 0 - g.side * lateral
        goal_pos[2] = g.handle[2]
        return Step(_capped(move(s.eef_pos, goal_pos, CLOSE, yaw_err), PUSH_SPEED))
    if at_grip and s.gripper_width > 0.012:
        return Step(hold(CLOSE))  # close on the bar
    if s.gripper_width < OPEN_WIDTH:  # closed on nothing, or stale: open away from the handle
        return Step(move(s.eef_pos, s.eef_pos + UP * 0.02, OPEN))
    return Step(_approach(s, grip, g.pull, ahead, lateral, OPEN_PAD - slot - 0.001, yaw_err, OPEN,
                          _drawer_travel(s, obj, a, g), descend_at=grip))


OPEN_PAD = 0.042  # distance from the eef to each finger pad's middle with the gripper open
OPEN_TARGET = 0.155  # how far to pull a drawer out (LIBERO's open range starts at 0.14)


def contact_free(g: _Drawer) -> float:
    return g.front + 0.05


def _drawer_travel(s: SceneState, obj: str, a: Articulation, g: _Drawer) -> float:
    """Height to move above the drawer at: over its top and whatever sits in it."""
    owner = max((n for n in s.bodies if obj.startswith(n + "_")), key=len, default="")
    return _travel_height(s, a.part.lo, a.part.hi, max(g.top, g.handle[2] + 0.03), skip=owner)


def _approach(s: SceneState, ready: np.ndarray, pull: np.ndarray, ahead: float, lateral: float,
              contact: float, yaw_err: float, gripper: float, travel_z: float,
              descend_at: np.ndarray | None = None) -> np.ndarray:
    """Get to ``ready`` (in front of a handle, level with it) without sweeping through
    anything: up to ``travel_z`` unless already in front of the fixture, across, then down.

    ``ahead``/``lateral`` are the eef's offsets from the handle along ``pull`` and across it;
    ``descend_at`` (default ``ready``) is where to go straight down from above."""
    target = ready if descend_at is None else descend_at
    err = target - s.eef_pos
    in_column = np.linalg.norm(err[:2]) < 0.015
    if in_column and abs(yaw_err) < YAW_TOL:
        return move(s.eef_pos, target, gripper, yaw_err)  # straight down (or up) onto it
    # Not above the ready point: travel high. Rise first if low and not clearly in front of
    # the handle (where nothing of the fixture is in the way).
    high = max(travel_z, target[2] + 0.04)
    if s.eef_pos[2] < high - 0.02 and not (ahead > contact + 0.02 and s.eef_pos[2] > target[2] + 0.03):
        return move(s.eef_pos, np.array([*s.eef_pos[:2], high]), gripper, yaw_err)
    z = max(s.eef_pos[2], target[2] + 0.03)
    return move(s.eef_pos, np.array([target[0], target[1], z]), gripper, yaw_err)


def _back_off(s: SceneState, handle: np.ndarray, pull: np.ndarray, ahead: float, contact: float) -> Step:
    """Retreat straight out from a handle, then report done."""
    if ahead > contact + CLEARANCE - 0.01:
        return Step(hold(s_gripper(s)), done=True)
    goal_pos = s.eef_pos + pull * (contact + CLEARANCE - ahead) + UP * 0.01
    return Step(move(s.eef_pos, goal_pos, s_gripper(s)))


def s_gripper(s: SceneState) -> float:
    """Keep the gripper as it is (closed stays closed, open stays open)."""
    return CLOSE if s.gripper_width < 0.04 else OPEN


def _capped(action: np.ndarray, cap: float) -> np.ndarray:
    """Scale the translation so no axis exceeds ``cap``."""
    out = action.copy()
    peak = np.abs(out[:3]).max()
    if peak > cap:
        out[:3] *= cap / peak
    return out


ARTICULATED_SKILLS: dict = {"close": close_drawer}
