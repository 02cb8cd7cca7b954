"""The motion helpers the expert's skills share: gains, the hand's pose and yaw, fixture joints,
what stands in the way. Everything here is a function of the current `SceneState` (or of plain
vectors), as the skills themselves are (`skills`, `articulated`, `lay`, `shelf`, `shelf_slide`,
`stow`, `upright`).

Conventions (robosuite OSC_POSE): position deltas are scaled by 0.05 m per unit, rotation
deltas (world-frame axis-angle) by 0.5 rad per unit; gripper -1 opens, +1 closes.
"""

from __future__ import annotations

import numpy as np

from seal.sim.scene import Articulation, Body, SceneState, openness

POS_GAIN = 20.0  # action per metre of position error (saturates at 5 cm)
YAW_GAIN = 2.0  # action per radian of yaw error
TILT_GAIN = 1.5  # rotation action per radian of roll/pitch error
WRIST_SAFE = 2.2  # the wrist's last joint (stops at +-2.9) is kept within this while turning
WRIST_MID_YAW = 2.6  # finger-axis yaw with the wrist's last joint mid-range, arm at rest (measured)

UP = np.array([0.0, 0.0, 1.0])
DOWN = -UP


# ---- geometry ----------------------------------------------------------------------------
def unit(v: np.ndarray) -> np.ndarray:
    return v / (np.linalg.norm(v) + 1e-12)


def flat(v: np.ndarray) -> np.ndarray:
    """Horizontal part of a vector."""
    return np.array([v[0], v[1], 0.0])


def hand_frame(finger: np.ndarray, point: np.ndarray) -> np.ndarray:
    """End-effector orientation with the fingers pointing along ``point`` and closing along
    ``finger`` (columns: finger axis, z x finger, pointing direction)."""
    z = unit(point)
    x = unit(finger - (finger @ z) * z)
    return np.stack([x, np.cross(z, x), z], axis=1)


def rotvec(rot: np.ndarray) -> np.ndarray:
    """Axis * angle of a rotation matrix."""
    angle = float(np.arccos(np.clip((np.trace(rot) - 1) / 2, -1.0, 1.0)))
    if angle < 1e-6:
        return np.zeros(3)
    if angle > np.pi - 1e-3:  # half turn: the axis is the eigenvector of eigenvalue 1
        w, v = np.linalg.eigh((rot + rot.T) / 2)
        return v[:, np.argmax(w)] * angle
    axis = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]])
    return axis / (2 * np.sin(angle)) * angle


def horizontal_frame(body: Body) -> tuple[float, np.ndarray]:
    """(yaw of the object's first horizontal local axis, its extents along that axis and the
    other horizontal one). Objects whose local z is vertical give (body.yaw, ext[:2]); others
    (LIBERO's bottles stand along local y) give their real horizontal sides."""
    w, x, y, z = body.quat
    rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                    [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                    [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    up = int(np.argmax(np.abs(rot[2])))
    i, j = [k for k in range(3) if k != up]
    ext = body.local_hi - body.local_lo
    return float(np.arctan2(rot[1, i], rot[0, i])), np.array([ext[i], ext[j]])


# ---- the scene: fixture joints, holders, what stands in the way ----------------------------
def joint_of(s: SceneState, obj: str, want_open: bool) -> Articulation:
    """The joint behind a fixture or region; of several (a whole cabinet), one not yet there."""
    names = s.joints_of.get(obj, ())
    if not names:
        raise KeyError(f"{obj!r} has no articulated joint; known: {sorted(s.joints_of)}")
    joints = [s.articulations[n] for n in names]
    return min(joints, key=lambda a: openness(a) if want_open else -openness(a))


def holder_of(s: SceneState, target: str) -> str | None:
    """The fixture or object a region belongs to (a cabinet, a basket), None for a table region."""
    owner = max((n for n in s.bodies if target.startswith(n + "_")), key=len, default=None)
    return None if owner is None or owner.endswith("_table") else owner


def path_top(s: SceneState, start: np.ndarray, end: np.ndarray, own: str, reach: float) -> float:
    """Top of the tallest other object within ``reach`` of the straight path start -> end."""
    ts = np.linspace(0.0, 1.0, 12)[:, None]
    path = start[None] + ts * (end - start)[None]
    top = s.table_z
    for n, b in s.bodies.items():
        if n == own or b.lo[2] > s.table_z + 0.3:  # shelves and wall fixtures are out of reach
            continue
        inside = np.all((path >= b.lo[:2] - reach) & (path <= b.hi[:2] + reach), axis=1)
        if inside.any():
            top = max(top, b.hi[2])
    return top


# ---- the finger axis's yaw -----------------------------------------------------------------
def wrap(angle: float) -> float:
    """Into [-pi/2, pi/2): a parallel gripper is symmetric under a half turn."""
    return (angle + np.pi / 2) % np.pi - np.pi / 2


# The wrist's last joint turns the finger axis about 1:1 and stops at +-2.9 rad; its middle
# is at a finger yaw of ~2.4 (measured: q7 = 0), the home pose at ~pi/2 (q7 = pi/4). Near
# the table the wrist's other joints drift along with it, so big turns run into the stops
# and the arm stalls. Finger yaws are therefore kept within a quarter turn (plus a margin)
# of home, and never wrapped through the far side where the stops are.
HOME_YAW = np.pi / 2
# (pick and place's window is centred on this measurement; the fixture skills' `WRIST_MID_YAW`,
# 2.6, was measured with the arm at rest and serves only when the arm's joints are unknown)
WINDOW_MID_YAW = 2.4
YAW_WINDOW = np.pi / 2 + 0.25


def _wrist_yaw(s: SceneState) -> float:
    """The finger yaw unwrapped around the wrist's mid-range (continuous over its travel)."""
    return (finger_yaw(s) - WINDOW_MID_YAW + np.pi) % (2 * np.pi) - np.pi + WINDOW_MID_YAW


def yaw_error(s: SceneState, yaw: float) -> float:
    """Signed turn onto ``yaw`` or its half-turn twin: of the twins within the window around
    home, the one nearer the current yaw (so the choice does not flip near the window's edge).
    """
    now = _wrist_yaw(s)
    base = HOME_YAW + wrap(yaw - HOME_YAW)
    twins = [t for t in (base - np.pi, base, base + np.pi) if abs(t - HOME_YAW) <= YAW_WINDOW]
    return float(min(twins, key=lambda t: abs(t - now)) - now)


def finger_yaw(s: SceneState) -> float:
    return float(np.arctan2(s.finger_axis[1], s.finger_axis[0]))


def yaw_toward(s: SceneState, finger_dir: np.ndarray, signed: bool = False) -> float:
    """Yaw that turns the finger axis onto ``finger_dir`` (``signed``: pad to pad exactly;
    else either way round, whichever keeps the wrist nearer the middle of its range).

    Angles are measured from the wrist's mid-range and never wrap through the opposite
    direction, where its last joint hits its stops: the wrist may turn the long way round
    rather than into a stop."""
    now = _wrist(s, finger_yaw(s))
    target = _wrist(s, _yaw_of(finger_dir if signed else wrist_side(s, finger_dir)))
    return target - now


def wrist_side(s: SceneState, finger_dir: np.ndarray, then: float = 0.0) -> np.ndarray:
    """Of ``finger_dir`` and its opposite (the same grip for a symmetric gripper), the one
    that leaves the wrist nearest the middle of its range after a further ``then`` radians
    of yaw; ties go to the nearer one, so the choice does not flip back and forth."""
    now = _wrist(s, finger_yaw(s))

    def cost(d: np.ndarray) -> float:
        t = _wrist(s, _yaw_of(d))
        return abs(t + then) + 0.5 * abs(t - now)

    return min((finger_dir, -finger_dir), key=cost)


def misalign(s: SceneState, finger_dir: np.ndarray) -> float:
    """Angle between the finger axis and ``finger_dir``, either way round (0..pi/2)."""
    d = (_yaw_of(finger_dir) - finger_yaw(s)) % np.pi
    return float(min(d, np.pi - d))


def _wrist(s: SceneState, yaw: float) -> float:
    """A finger-axis yaw as an offset from the wrist's mid-range, in [-pi, pi): minus the
    angle the wrist's last joint would have there, with the gripper pointing down (yaw +1
    turns that joint by -1, measured). Without the arm's joint positions, WRIST_MID_YAW is
    where that joint is mid-range with the arm near its rest pose."""
    mid = finger_yaw(s) + float(s.arm_qpos[6]) if len(s.arm_qpos) >= 7 else WRIST_MID_YAW
    return (yaw - mid + np.pi) % (2 * np.pi) - np.pi


def _yaw_of(v: np.ndarray) -> float:
    return float(np.arctan2(v[1], v[0]))


# ---- actions -------------------------------------------------------------------------------
def hand_tilt(s: SceneState) -> float:
    """Angle between the fingers' pointing direction and straight down."""
    return float(np.arccos(np.clip(-s.eef_xmat[2, 2], -1.0, 1.0)))


def act(s: SceneState, goal: np.ndarray, gripper: float, finger_dir: np.ndarray | None = None,
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
    rot = TILT_GAIN * np.cross(s.eef_xmat[:, 2], unit(point))  # world-frame axis * sin(angle)
    rot[2] = 0.0
    if finger_dir is not None:
        rot[2] = YAW_GAIN * yaw_toward(s, finger_dir, signed)
    return np.array([*delta, *np.clip(rot, -1.0, 1.0), gripper])


def _pose_rotation(s: SceneState, finger: np.ndarray, point: np.ndarray) -> np.ndarray:
    """World-frame axis*angle from the current orientation to the target, the finger axis
    either way round: the smaller turn, unless it would take the wrist's last joint (which
    turns the hand about its pointing axis, by +1 rad per rad, measured) near its stops."""
    options = [rotvec(hand_frame(f, point) @ s.eef_xmat.T) for f in (finger, -finger)]
    wrist = float(s.arm_qpos[6]) if len(s.arm_qpos) >= 7 else 0.0

    def cost(v: np.ndarray) -> float:
        after = abs(wrist + float(v @ s.eef_xmat[:, 2]))
        return float(np.linalg.norm(v)) + 10.0 * max(0.0, after - WRIST_SAFE)

    return min(options, key=cost)


def pose_error(s: SceneState, finger: np.ndarray, point: np.ndarray) -> float:
    return float(np.linalg.norm(_pose_rotation(s, finger, point)))


def act_pose(s: SceneState, goal: np.ndarray, gripper: float, finger: np.ndarray, point: np.ndarray,
              cap: float = 1.0) -> np.ndarray:
    """Like `act`, with the whole orientation steered from the eef frame (for poses where
    the finger axis is not horizontal, so yaw alone says nothing)."""
    action = act(s, goal, gripper, cap=cap)
    action[3:6] = np.clip(TILT_GAIN * _pose_rotation(s, finger, point), -1.0, 1.0)
    return action
