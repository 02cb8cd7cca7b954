"""Long-handled pans (LIBERO's frying pan): where to hold one.

A frying pan is a wide, shallow dish (about 19 cm across, 4 cm walls) with a 18 cm handle.
Across its body it is far wider than the open gripper (7.6 cm), and its box centre lies on
the dish's floor near the handle's root, where a box grasp closes on nothing. Its handle,
though, is a bar 2.5 cm wide and 1.2 cm thick: held across it, from above, the hand stays
off the dish, so the pan can be set down on a stove or slid into a shelf while the hand
stays outside. The pan weighs 50 g, so a pinch some 16 cm from its centre holds it nearly level.

The handle's place is read off the collision geoms once and kept here in the pan's own frame
(like `skills.CUP_OFFSET` for mugs): which local axis it points along, and a point on its
centre line. The world pose then follows the pan's current pose, tilted or not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.sim.scene import Body, SceneState


@dataclass(frozen=True)
class PanHandle:
    axis: tuple[float, float, float]  # unit vector from the dish's centre along the handle, local frame
    grip: float  # distance from the body origin (the dish's centre) to the pinch, along ``axis``
    height: float  # the handle's centre line above the origin (the dish's bottom) at the pinch


# chefmate_8_frypan: the handle geom (g1) runs along local +x from 0.126 to 0.259 m off the
# dish's centre, rising 7 degrees, its centre line 4.4 cm up at 0.192 m. Pinched at 0.16 m:
# clear of the dish's rim (0.10 m) and far enough out that the hand (4.1 cm half-thickness
# across the handle) stays in front of a shelf's face; near enough to the dish that the pan
# hangs nearly level (pinched at 0.20 m it drooped 17 degrees and more in one init of 6).
PAN_HANDLES = {"chefmate_8_frypan": PanHandle(axis=(1.0, 0.0, 0.0), grip=0.16, height=0.041)}


MAX_DROOP = np.radians(20)  # while lifting, more tilt than this means the handle turned in the pads
LIFT_RATE = 0.4  # lifting speed (action units, ~5 mm per step at 0.4)
UPRIGHT_GAIN = 0.6  # rotation action per radian of the held pan's tilt
MAX_HAND_TILT = 0.5  # radians the hand may lean off pointing down to keep the pan level


def pan_handle(name: str) -> PanHandle | None:
    return next((h for k, h in PAN_HANDLES.items() if k in name), None)


def is_pan(name: str) -> bool:
    return pan_handle(name) is not None


def rotation(body: Body) -> np.ndarray:
    w, x, y, z = body.quat
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def tilt(body: Body) -> float:
    """Radians between the pan's up axis and the world's."""
    return float(np.arccos(np.clip(rotation(body)[2, 2], -1.0, 1.0)))


def leveling(s: SceneState, body: Body) -> np.ndarray:
    """Rotation action (world x, y) that leans the hand against a held object's tilt.

    Pinched at its handle, a pan's dish droops about the finger axis: the pads' grip turns
    on the bar under the dish's weight (most of all while its far rim still rests on the
    table at lift-off). Turning the hand the other way brings the dish back up; the lean is
    limited so the hand does not end up on its side."""
    up = rotation(body)[:, 2]
    fix = UPRIGHT_GAIN * np.cross(up, [0.0, 0.0, 1.0])
    lean = float(np.arccos(np.clip(-s.eef_xmat[2, 2], -1.0, 1.0)))
    if lean > MAX_HAND_TILT:  # do not lean further
        away = np.cross(s.eef_xmat[:, 2], [0.0, 0.0, -1.0])
        fix = fix - min(0.0, float(fix @ away)) * away / (away @ away + 1e-12)
    return np.clip(fix[:2], -1.0, 1.0)


def handle_direction(name: str, body: Body) -> np.ndarray:
    """Unit 2-vector (world x, y) from the dish's centre toward the handle's end."""
    h = pan_handle(name)
    d = (rotation(body) @ np.array(h.axis))[:2]
    return d / (np.linalg.norm(d) + 1e-9)


def handle_grasps(s: SceneState, name: str) -> list[tuple[np.ndarray, float, float]]:
    """Candidate pinches of the pan's handle from above: (eef point, finger yaw, preference
    cost); empty if ``name`` is not a pan. The preferred one is across the handle at the
    nominal grip; others slide along the handle or skew the fingers up to 30 degrees (a 2.5 cm
    bar still fits the open hand), for when a neighbour (a moka pot by the handle) would be
    under the hand."""
    h = pan_handle(name)
    if h is None:
        return []
    body = s.bodies[name]
    rot = rotation(body)
    d = handle_direction(name, body)
    across = float(np.arctan2(d[0], -d[1]))
    out = []
    for grip in (h.grip, h.grip + 0.03, h.grip - 0.02, h.grip + 0.06):  # pads stay on the bar
        # The handle rises 7 degrees toward its end.
        local = grip * np.array(h.axis) + np.array([0.0, 0.0, h.height + 0.12 * (grip - h.grip)])
        point = body.pos + rot @ local
        for skew in (0.0, np.pi / 6, -np.pi / 6):
            out.append((point, across + skew, 0.5 * abs(grip - h.grip) + 0.02 * abs(skew)))
    return out
