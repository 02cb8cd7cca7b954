"""The one narrow, privileged view of a LIBERO world that scripted policies may read.

A real VLA sees only images and proprioception. The scripted expert (our stand-in for a
reasoning VLA on this machine) also needs object poses and sizes, region boxes and joint
angles. Everything it may read is in `SceneState`: plain arrays, picklable, so it travels
with an observation from a pool worker to the policy. Nothing else of the simulator leaks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np


@dataclass(frozen=True)
class Body:
    """An object or fixture: pose, and its extent in its own frame and in the world."""

    pos: np.ndarray  # (3,) body origin, world frame
    quat: np.ndarray  # (4,) wxyz
    local_lo: np.ndarray  # (3,) box around its geoms, in the body's own frame
    local_hi: np.ndarray
    lo: np.ndarray  # (3,) axis-aligned box around its geoms, world frame
    hi: np.ndarray
    # A movable object's collision geoms one by one (empty for fixtures): the shape under the
    # overall box, e.g. a bottle's neck is much narrower than its body.
    parts: tuple[Box, ...] = ()

    @property
    def center(self) -> np.ndarray:
        return (self.lo + self.hi) / 2

    @property
    def size(self) -> np.ndarray:
        return self.hi - self.lo

    @property
    def yaw(self) -> float:
        w, x, y, z = self.quat
        return float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


@dataclass(frozen=True)
class Site:
    """A region (LIBERO site): position, orientation and half-sizes."""

    pos: np.ndarray
    xmat: np.ndarray  # (3, 3)
    size: np.ndarray


@dataclass(frozen=True)
class Box:
    """One collision geom's bounding box: centre and orientation in the world, half-sizes."""

    center: np.ndarray  # (3,) world
    xmat: np.ndarray  # (3, 3) the box's axes as columns, world frame
    half: np.ndarray  # (3,) half-sizes along its own axes

    @property
    def lo(self) -> np.ndarray:  # axis-aligned world box around it
        return self.center - np.abs(self.xmat) @ self.half

    @property
    def hi(self) -> np.ndarray:
        return self.center + np.abs(self.xmat) @ self.half


@dataclass(frozen=True)
class Articulation:
    """A fixture's hinge or slide joint and the part it moves (a drawer, a door, a knob).

    LIBERO's convention: every articulated fixture is closed / off near ``qpos == 0`` and
    opens toward the far end of ``range``.
    """

    kind: str  # "hinge" or "slide"
    qpos: float
    range: np.ndarray  # (2,) joint limits
    axis: np.ndarray  # (3,) unit joint axis, world frame
    anchor: np.ndarray  # (3,) a point on the axis, world frame
    part: Body  # the moving body's pose, and the box around the geoms it carries
    geoms: tuple[Box, ...] = ()  # the moving part's collision geoms (handles are among them)


def open_sign(a: Articulation) -> float:
    """+1 if opening increases qpos (the range's far end from 0 is positive), else -1."""
    lo, hi = a.range
    return 1.0 if abs(hi) >= abs(lo) else -1.0


def openness(a: Articulation) -> float:
    """How far from closed (metres for a slide, radians for a hinge); 0 when closed."""
    return a.qpos * open_sign(a)


def open_fraction(a: Articulation) -> float:
    """How far open, as a fraction of the joint's travel from closed (0) to its far limit (1)."""
    far = max(abs(float(a.range[0])), abs(float(a.range[1])))
    return float(np.clip(openness(a) / far, 0.0, 1.0)) if far > 0 else 0.0


@dataclass
class SceneState:
    eef_pos: np.ndarray  # (3,) end-effector site, world frame
    eef_xmat: np.ndarray  # (3, 3) end-effector orientation
    finger_axis: np.ndarray  # (3,) unit vector from one finger pad to the other
    gripper_width: float  # distance between the finger pads' joints (~0.08 open, ~0 closed)
    bodies: dict[str, Body] = field(default_factory=dict)
    sites: dict[str, Site] = field(default_factory=dict)
    joints: dict[str, float] = field(default_factory=dict)  # articulated fixtures' joints
    facts: dict[str, bool] = field(default_factory=dict)  # goal atoms asked for -> truth
    table_z: float = 0.0  # height of the table top under the scene
    # Articulated fixtures' joints in full (keyed by joint name), and which joints
    # move each fixture or region (e.g. white_cabinet_1_bottom_region -> its drawer's slide).
    articulations: dict[str, Articulation] = field(default_factory=dict)
    joints_of: dict[str, tuple[str, ...]] = field(default_factory=dict)
    # The arm's own joint positions (proprioception), base to wrist: lets a primitive notice
    # a posture the controller cannot leave by itself (e.g. the elbow locked straight).
    arm_qpos: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # Static fixtures' collision geoms one by one (a shelf's boards and walls, a caddy's
    # dividers): a fixture's overall box hides its openings, e.g. which side a shelf is open on.
    fixture_boxes: dict[str, tuple[Box, ...]] = field(default_factory=dict)


class SceneReader:
    """Reads `SceneState` from a robosuite/LIBERO env; geometry lookups are prepared once."""

    def __init__(self, env):
        self._env = env
        m = env.sim.model._model
        self._model = m
        self._geoms: dict[str, np.ndarray] = {}
        names = list(env.objects_dict) + list(env.fixtures_dict)
        self._movable = set(env.objects_dict)
        for name in names:
            root = env.obj_body_id[name]
            subtree = {b for b in range(m.nbody) if _is_descendant(m, b, root)}
            geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] in subtree]
            colliding = [g for g in geoms if m.geom_contype[g] or m.geom_conaffinity[g]]
            self._geoms[name] = np.array(colliding or geoms, dtype=np.int64)
        self._joints = {
            m.joint(j).name: int(m.jnt_qposadr[j])
            for j in range(m.njnt)
            if any(m.joint(j).name.startswith(f"{f}_") for f in env.fixtures_dict)
            and int(m.jnt_type[j]) in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
        }
        self._articulated, self._joints_of = self._prepare_articulations(env)
        robot = env.robots[0]
        self._eef_site = robot.eef_site_id
        self._grip_qpos = list(robot._ref_gripper_joint_pos_indexes)
        self._arm_qpos = list(robot._ref_joint_pos_indexes)
        pads = robot.gripper.important_geoms
        self._pad_left = m.geom(pads["left_fingerpad"][0]).id
        self._pad_right = m.geom(pads["right_fingerpad"][0]).id
        self._table_z = _table_height(env)
        # Fixtures with no moving parts (articulated ones are described by `articulations`);
        # the table is left out (it is `table_z`).
        self._static = tuple(n for n in env.fixtures_dict
                             if n not in self._joints_of and not n.endswith("_table") and n in self._geoms)

    def read(self, facts: dict[str, bool] | None = None) -> SceneState:
        d = self._env.sim.data._data
        left, right = d.geom_xpos[self._pad_left], d.geom_xpos[self._pad_right]
        axis = right - left
        grip = d.qpos[self._grip_qpos]
        return SceneState(
            eef_pos=d.site_xpos[self._eef_site].copy(),
            eef_xmat=d.site_xmat[self._eef_site].reshape(3, 3).copy(),
            finger_axis=axis / (np.linalg.norm(axis) + 1e-9),
            gripper_width=float(grip[0] - grip[1]),
            bodies={name: self._body(name, d) for name in self._geoms},
            sites=self._sites(d),
            joints={name: float(d.qpos[adr]) for name, adr in self._joints.items()},
            facts=dict(facts or {}),
            table_z=self._table_z,
            articulations={name: self._articulation(name, d) for name in self._articulated},
            joints_of=self._joints_of,
            arm_qpos=d.qpos[self._arm_qpos].copy(),
            fixture_boxes={name: self._boxes(self._geoms[name], d) for name in self._static},
        )

    def _boxes(self, geoms: np.ndarray, d) -> tuple[Box, ...]:
        m = self._model
        out = []
        for g in geoms:
            gmat = d.geom_xmat[g].reshape(3, 3)
            out.append(Box(center=d.geom_xpos[g] + gmat @ m.geom_aabb[g, :3], xmat=gmat.copy(),
                           half=m.geom_aabb[g, 3:].copy()))
        return tuple(out)

    def _prepare_articulations(self, env):
        """Per articulated joint: its id and the colliding geoms of the part it moves; and
        per fixture or region, the joints that move it."""
        m = self._model
        kinds = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
        out = {}
        for j in range(m.njnt):
            name = m.joint(j).name
            if int(m.jnt_type[j]) not in kinds or not any(name.startswith(f"{f}_") for f in env.fixtures_dict):
                continue
            root = int(m.jnt_bodyid[j])
            geoms = [g for g in range(m.ngeom) if _is_descendant(m, int(m.geom_bodyid[g]), root)
                     and (m.geom_contype[g] or m.geom_conaffinity[g])]
            out[name] = (j, np.array(geoms, dtype=np.int64))
        joints_of: dict[str, tuple[str, ...]] = {}
        for name in env.fixtures_dict:
            joints_of[name] = tuple(j for j in env.get_object(name).joints if j in out)
        for name, site in env.object_sites_dict.items():
            joints = tuple(j for j in (getattr(site, "joints", None) or ()) if j in out)
            if joints:
                joints_of[name] = joints
        return out, {k: v for k, v in joints_of.items() if v}

    def _articulation(self, name: str, d) -> Articulation:
        m = self._model
        j, geoms = self._articulated[name]
        bid = int(m.jnt_bodyid[j])
        pos, quat = d.xpos[bid].copy(), d.xquat[bid].copy()
        rot = d.xmat[bid].reshape(3, 3)
        if len(geoms):
            corners = _geom_corners(m, d, geoms)
            local = (corners - pos) @ rot
            part = Body(pos=pos, quat=quat, local_lo=local.min(0), local_hi=local.max(0),
                        lo=corners.min(0), hi=corners.max(0))
        else:
            zero = np.zeros(3)
            part = Body(pos=pos, quat=quat, local_lo=zero, local_hi=zero, lo=pos.copy(), hi=pos.copy())
        boxes = _boxes(m, d, geoms)
        hinge = int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE)
        return Articulation(kind="hinge" if hinge else "slide", qpos=float(d.qpos[m.jnt_qposadr[j]]),
                            range=m.jnt_range[j].copy(), axis=d.xaxis[j].copy(), anchor=d.xanchor[j].copy(),
                            part=part, geoms=tuple(boxes))

    def _body(self, name: str, d) -> Body:
        bid = self._env.obj_body_id[name]
        pos, quat = d.xpos[bid].copy(), d.xquat[bid].copy()
        rot = d.xmat[bid].reshape(3, 3)
        corners = _geom_corners(self._model, d, self._geoms[name])  # (n, 3) world
        local = (corners - pos) @ rot
        parts = _boxes(self._model, d, self._geoms[name]) if name in self._movable else ()
        return Body(pos=pos, quat=quat, local_lo=local.min(0), local_hi=local.max(0),
                    lo=corners.min(0), hi=corners.max(0), parts=parts)

    def _sites(self, d) -> dict[str, Site]:
        m = self._model
        out = {}
        for name in self._env.object_sites_dict:
            sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
            if sid >= 0:
                out[name] = Site(pos=d.site_xpos[sid].copy(), xmat=d.site_xmat[sid].reshape(3, 3).copy(),
                                 size=m.site_size[sid].copy())
        return out


_SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)


def _boxes(m, d, geoms: np.ndarray) -> tuple[Box, ...]:
    """Each geom's bounding box, posed in the world."""
    out = []
    for g in geoms:
        gmat = d.geom_xmat[g].reshape(3, 3)
        centre, half = m.geom_aabb[g, :3], m.geom_aabb[g, 3:]
        out.append(Box(center=d.geom_xpos[g] + gmat @ centre, xmat=gmat.copy(), half=half.copy()))
    return tuple(out)


def _geom_corners(m, d, geoms: np.ndarray) -> np.ndarray:
    """World positions of the 8 corners of each geom's bounding box."""
    aabb = m.geom_aabb[geoms]  # (n, 6): centre (3), half-size (3), in the geom's frame
    local = aabb[:, None, :3] + _SIGNS[None] * aabb[:, None, 3:]  # (n, 8, 3)
    rot = d.geom_xmat[geoms].reshape(-1, 3, 3)
    world = np.einsum("nij,nkj->nki", rot, local) + d.geom_xpos[geoms][:, None, :]
    return world.reshape(-1, 3)


def _is_descendant(m, body: int, root: int) -> bool:
    while body > 0:
        if body == root:
            return True
        body = m.body_parentid[body]
    return body == root


def _table_height(env) -> float:
    """Height of the static surface under the workspace (table top, or floor).

    Cast rays straight down over a small grid around the workspace centre, skip anything
    that moves (objects, the robot), and take the median height of the static hits.
    """
    m, d = env.sim.model._model, env.sim.data._data
    centre = np.asarray(getattr(env, "workspace_offset", (0.0, 0.0, 0.0)), dtype=np.float64)
    geomid = np.zeros(1, dtype=np.int32)
    down = np.array([0.0, 0.0, -1.0])
    heights = []
    for dx in (-0.15, 0.0, 0.15):
        for dy in (-0.15, 0.0, 0.15):
            start = np.array([centre[0] + dx, centre[1] + dy, 3.0])
            for _ in range(10):  # step through moving geoms until a static one is hit
                dist = mujoco.mj_ray(m, d, start, down, None, 1, -1, geomid)
                if dist < 0:
                    break
                hit = start + dist * down
                if m.body_weldid[m.geom_bodyid[geomid[0]]] == 0:
                    heights.append(hit[2])
                    break
                start = hit + 1e-4 * down
    return float(np.median(heights)) if heights else float(centre[2])
