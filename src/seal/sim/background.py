"""Visual-viewpoint variants: another room's background behind the same table, and a moved camera.

A LIBERO scene file (``assets/scenes/libero_*_base_style.xml``) holds two kinds of things: the
table the task is set on (physical; the problem class looks it up by name) and the room around
it - floor and wall textures, visual-only furniture behind the robot (a kitchen counter and
fridge, a living-room wall unit, a study bookshelf and plant) and room lights. A background swap
keeps the task's own table and physics, and replaces the room: the donor room's floor and wall
styles (passed to the problem class as ``scene_properties``) and its furniture and lights
(spliced into a copy of the task's scene file). Nothing here collides, so init states and
dynamics are those of the original task.

The camera change is an orbit of the agent-view camera around the point it looks at on the
table, so the workspace stays centred; ``objects_in_view`` checks that every object does.
"""

from __future__ import annotations

import copy
import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seal.errors import InvalidInput


@dataclass(frozen=True)
class Room:
    name: str
    scene_xml: str  # relative to LIBERO's assets directory
    floor_style: str
    wall_style: str


# The three tabletop rooms of LIBERO-10/90 with the styles their problem classes use.
ROOMS = {
    "kitchen": Room("kitchen", "scenes/libero_kitchen_tabletop_base_style.xml", "gray-ceramic", "yellow-linen"),
    "living_room": Room("living_room", "scenes/libero_living_room_tabletop_base_style.xml", "wood-plank",
                        "light-gray-plaster"),
    "study": Room("study", "scenes/libero_study_base_style.xml", "light-gray", "light-gray-plaster"),
}
# BDDL problem name -> its room.
PROBLEM_ROOMS = {
    "LIBERO_Kitchen_Tabletop_Manipulation": "kitchen",
    "LIBERO_Living_Room_Tabletop_Manipulation": "living_room",
    "LIBERO_Study_Tabletop_Manipulation": "study",
}
_SHARED_LIGHTS = ("light1", "light2")  # every room has these two overhead lights
_BACKGROUND_X = -1.0  # furniture further back than this (behind the robot base) is background


def room_of_problem(problem: str) -> str:
    if problem not in PROBLEM_ROOMS:
        raise InvalidInput(f"no LIBERO room for problem {problem!r}; known: {', '.join(PROBLEM_ROOMS)}")
    return PROBLEM_ROOMS[problem]


def _assets_dir() -> Path:
    from libero.libero import get_libero_path

    return Path(get_libero_path("assets")).resolve()


def _absolute_files(root: ET.Element, folder: Path) -> None:
    for node in root.iter():
        f = node.get("file")
        if f is not None and not os.path.isabs(f):
            node.set("file", str((folder / f).resolve()))


def _is_background(geom: ET.Element) -> bool:
    if geom.get("type") != "mesh" or geom.get("contype") != "0" or geom.get("conaffinity") != "0":
        return False
    pos = [float(v) for v in (geom.get("pos") or "0 0 0").split()]
    return pos[0] < _BACKGROUND_X


def _background_parts(root: ET.Element) -> tuple[list[ET.Element], list[ET.Element], list[ET.Element]]:
    """(background geoms, room lights, the assets only those geoms use) of a scene file."""
    world = root.find("worldbody")
    geoms = [g for g in world.findall("geom") if _is_background(g)]
    lights = [l for l in world.findall("light") if l.get("name") not in _SHARED_LIGHTS]
    asset = root.find("asset")
    meshes = {g.get("mesh") for g in geoms}
    materials = {g.get("material") for g in geoms}
    used_elsewhere = {g.get("material") for g in root.iter("geom") if g not in geoms}
    materials -= used_elsewhere
    textures = {m.get("texture") for m in asset.findall("material") if m.get("name") in materials}
    assets = [a for a in asset
              if (a.tag == "mesh" and a.get("name") in meshes)
              or (a.tag == "material" and a.get("name") in materials)
              or (a.tag == "texture" and a.get("name") in textures and a.get("name") not in ("texplane", "tex-wall"))]
    return geoms, lights, assets


def swapped_scene_xml(own_room: str, donor_room: str) -> str:
    """The task's own scene file with its room background replaced by ``donor_room``'s."""
    for r in (own_room, donor_room):
        if r not in ROOMS:
            raise InvalidInput(f"unknown room {r!r}; valid: {', '.join(ROOMS)}")
    assets = _assets_dir()
    own_path, donor_path = assets / ROOMS[own_room].scene_xml, assets / ROOMS[donor_room].scene_xml
    own, donor = ET.parse(own_path).getroot(), ET.parse(donor_path).getroot()
    _absolute_files(own, own_path.parent)
    _absolute_files(donor, donor_path.parent)
    geoms, lights, used = _background_parts(own)
    world, asset = own.find("worldbody"), own.find("asset")
    for g in geoms + lights:
        world.remove(g)
    for a in used:
        asset.remove(a)
    d_geoms, d_lights, d_assets = _background_parts(donor)
    taken = {a.get("name") for a in asset}
    for a in d_assets:
        if a.get("name") not in taken:
            asset.append(copy.deepcopy(a))
    # Insert before the shared lights so the file keeps its layout (geoms, then lights, then cameras).
    anchor = list(world).index(world.find("light")) if world.find("light") is not None else len(world)
    for i, node in enumerate(d_geoms + d_lights):
        world.insert(anchor + i, copy.deepcopy(node))
    return ET.tostring(own, encoding="unicode")


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "seal" / "scenes"


def scene_kwargs(own_room: str, donor_room: str) -> dict:
    """Keyword arguments for LIBERO's problem class that put the task in ``donor_room``'s room."""
    text = swapped_scene_xml(own_room, donor_room)
    out = cache_dir()
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{own_room}-in-{donor_room}-{hashlib.blake2b(text.encode(), digest_size=8).hexdigest()}.xml"
    if not path.is_file():  # several pool workers may build the same file: write aside, then rename
        fd, tmp = tempfile.mkstemp(dir=out, suffix=".xml")
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    donor = ROOMS[donor_room]
    return {"scene_xml": str(path),
            "scene_properties": {"floor_style": donor.floor_style, "wall_style": donor.wall_style}}


# ---- camera ------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraOrbit:
    """Move a fixed camera on a sphere around the table point it looks at.

    yaw_deg:   swing around the vertical axis through that point; positive moves the camera
               towards +y, the robot's left.
    pitch_deg: raise (positive) or lower the camera along the sphere.
    distance:  scale of the camera's distance to that point (>1 steps back).
    """

    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    distance: float = 1.0

    def __post_init__(self) -> None:
        if not (-60 <= self.yaw_deg <= 60 and -30 <= self.pitch_deg <= 30 and 0.7 <= self.distance <= 1.5):
            raise InvalidInput(f"camera orbit {self} out of range: yaw in [-60, 60] deg, pitch in [-30, 30] deg, "
                               "distance in [0.7, 1.5]")

    def describe(self) -> str:
        parts = []
        if self.yaw_deg:
            parts.append(f"swung {abs(self.yaw_deg):g} deg towards the robot's {'left' if self.yaw_deg > 0 else 'right'}")
        if self.pitch_deg:
            parts.append(f"{'raised' if self.pitch_deg > 0 else 'lowered'} {abs(self.pitch_deg):g} deg")
        if self.distance != 1.0:
            parts.append(f"{'stepped back' if self.distance > 1 else 'moved in'} to {self.distance:g}x the distance")
        return ", ".join(parts) or "unchanged"


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _mat_to_quat(m: np.ndarray) -> np.ndarray:
    import mujoco

    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(m, dtype=np.float64).reshape(9))
    return q


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def orbit_pose(pos: np.ndarray, quat: np.ndarray, orbit: CameraOrbit, target_z: float) -> tuple[np.ndarray, np.ndarray]:
    """New (pos, quat wxyz) of a camera at ``pos``/``quat`` orbited about the point where its
    optical axis meets the plane z = ``target_z``."""
    rot = _quat_to_mat(np.asarray(quat, dtype=np.float64))
    forward = -rot[:, 2]  # MuJoCo cameras look along their -z axis
    if forward[2] >= -1e-6:
        raise InvalidInput("camera does not look down at the table; cannot find an orbit centre")
    t = (target_z - pos[2]) / forward[2]
    pivot = pos + t * forward
    r_yaw = _axis_rotation(np.array([0.0, 0.0, 1.0]), np.radians(orbit.yaw_deg))
    # Pitch turns about the camera's own horizontal (x) axis; a positive angle raises it.
    r_pitch = _axis_rotation(rot[:, 0], -np.radians(orbit.pitch_deg))
    r = r_yaw @ r_pitch
    new_pos = pivot + orbit.distance * (r @ (pos - pivot))
    return new_pos, _mat_to_quat(r @ rot)


def project(model, data, camera: str, points: np.ndarray) -> np.ndarray:
    """Normalised image coordinates in [-1, 1] (x right, y up) of world points seen by ``camera``;
    points behind the camera get NaN."""
    import mujoco

    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
    if cam < 0:
        raise InvalidInput(f"unknown camera {camera!r}")
    rot = data.cam_xmat[cam].reshape(3, 3)
    rel = (np.atleast_2d(points) - data.cam_xpos[cam]) @ rot  # camera frame
    depth = -rel[:, 2]
    scale = 1.0 / np.tan(np.radians(model.cam_fovy[cam]) / 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = np.stack([rel[:, 0] / depth, rel[:, 1] / depth], axis=1) * scale
    xy[depth <= 0] = np.nan
    return xy
