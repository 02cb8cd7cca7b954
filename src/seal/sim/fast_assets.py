"""Fast render mode: the same scene drawn with decimated meshes and smaller textures.

On CPU rendering (Mesa llvmpipe) a LIBERO-10 frame costs ~11 ms fixed plus ~0.45 ms per
1k mesh faces drawn, and the scenes carry ~400k visual faces, so geometry dominates.
Here we build a *render-only* model of the scene in which every drawn mesh is
quadric-decimated, part by connected part, each part to the fewest faces that keep its area and
its surface (within ~1 mm near the robot, proportionally more for static scenery farther from
the camera), with texture coordinates kept in their chart; and every texture image is
downsampled. Physics never sees this model
(`SceneRenderer` copies positions into it before drawing), so collision geometry is
untouched where it matters - in the physics model. Only meshes a stock camera draws are
decimated (collision meshes, group 0, are hidden as robosuite hides them).

Prepared assets are cached on disk (``$XDG_CACHE_HOME/seal/fast_assets``), keyed by the
source mesh's content and the settings, so each mesh is decimated once per machine.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from seal.sim.render import VISIBLE_GEOM_GROUPS

CACHE_VERSION = 12


@dataclass(frozen=True)
class FastRenderSettings:
    face_ratio: float = 0.06  # each part starts at this share of its faces (doubled until its guards hold)
    min_faces: int = 200  # meshes this small stay intact
    texture_max: int = 256  # longest side of any texture image, in pixels
    max_area_change: float = 0.03  # a decimated part must keep its surface area within 3%
    # ... and 99% of its original vertices within this distance (metres) of the new surface:
    # ~a quarter of what one 224-px pixel covers on the table, 1 m from the agent camera.
    max_deviation: float = 0.001
    # Static scenery farther than this from the agent camera gets both tolerances scaled by
    # distance / this (a pixel covers proportionally more of it): the budget by projected size.
    # Anything that moves may come close to the wrist camera and keeps the tolerances as they are.
    reference_distance: float = 1.0


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "seal" / "fast_assets"


def build_fast_model(scene_xml: str, settings: FastRenderSettings = FastRenderSettings()) -> mujoco.MjModel:
    """Compile the render-only model of ``scene_xml`` (robosuite's full MJCF string)."""
    stock = mujoco.MjModel.from_xml_string(scene_xml)
    root = ET.fromstring(scene_xml)
    drawn = _drawn_mesh_ids(stock)
    slack = _distance_slack(stock, settings.reference_distance)
    out = cache_dir()
    out.mkdir(parents=True, exist_ok=True)
    for elem in root.iter("mesh"):
        if elem.get("file") is None:
            continue
        mesh_id = mujoco.mj_name2id(stock, mujoco.mjtObj.mjOBJ_MESH, elem.get("name"))
        if mesh_id in drawn:
            elem.set("file", str(_decimated_mesh(stock, mesh_id, elem, settings, out, slack.get(mesh_id))))
            for attr in ("scale", "refpos", "refquat"):  # baked into the written vertices
                elem.attrib.pop(attr, None)
    for elem in root.iter("texture"):
        if elem.get("file") is not None:
            elem.set("file", str(_small_texture(Path(elem.get("file")), settings.texture_max, out)))
    return mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))


def _distance_slack(model: mujoco.MjModel, reference: float) -> dict[int, np.ndarray]:
    """Per mesh, per vertex: how much its decimation tolerances may grow - its distance from the
    agent camera over ``reference`` (at least 1) where the mesh is static scenery, else 1. A room
    mesh wraps the whole scene, so the factor is per vertex, not per mesh."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "agentview")
    if cam < 0:
        return {}
    slack: dict[int, np.ndarray] = {}
    for g in range(model.ngeom):
        if model.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH:
            continue
        mesh = int(model.geom_dataid[g])
        v0, nv = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        if model.body_weldid[model.geom_bodyid[g]] == 0:  # welded to the world: never moves
            world = data.geom_xpos[g] + model.mesh_vert[v0:v0 + nv] @ data.geom_xmat[g].reshape(3, 3).T
            factor = np.maximum(1.0, np.linalg.norm(world - data.cam_xpos[cam], axis=1) / reference)
        else:  # it moves, and may come close to the wrist camera
            factor = np.ones(nv)
        slack[mesh] = factor if mesh not in slack else np.minimum(slack[mesh], factor)
    return slack


def _drawn_mesh_ids(model: mujoco.MjModel) -> set[int]:
    """Meshes some visible geom draws (alpha > 0, in a group a stock LIBERO camera shows)."""
    return {
        int(model.geom_dataid[g])
        for g in range(model.ngeom)
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH and model.geom_rgba[g][3] > 0
        and model.geom_group[g] in VISIBLE_GEOM_GROUPS
    }


def _atomic_write(path: Path, data: bytes) -> None:
    # Pool workers prepare the same assets at the same time: write aside, then rename.
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=path.suffix)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def _key(*parts) -> str:
    h = hashlib.blake2b(digest_size=10)
    for p in (CACHE_VERSION, *parts):
        h.update(repr(p).encode() if not isinstance(p, bytes) else p)
    return h.hexdigest()


@dataclass
class _Mesh:
    """One mesh as MuJoCo compiled it, in the asset's own (scaled) frame.

    Faces index ``verts``; every face corner also indexes a normal and (when textured) a
    texcoord, since MuJoCo keeps those per corner.
    """

    verts: np.ndarray  # (nv, 3)
    faces: np.ndarray  # (nf, 3) into verts
    normals: np.ndarray  # (nn, 3)
    face_normals: np.ndarray  # (nf, 3) into normals
    texcoords: np.ndarray | None = None  # (nt, 2)
    face_texcoords: np.ndarray | None = None  # (nf, 3) into texcoords
    source_faces: np.ndarray | None = None  # (nf,) after decimation: the original face each one is
    source_verts: np.ndarray | None = None  # (nv,) for a sub-mesh: the vertex of the whole mesh each one is


def _mesh_in_file_frame(model: mujoco.MjModel, i: int) -> _Mesh:
    """Mesh ``i`` with MuJoCo's re-centring undone.

    MuJoCo stores mesh vertices re-centred in the mesh's inertial frame and remembers that
    frame as mesh_pos/mesh_quat; undoing it lets the compiler place the new mesh exactly
    where the old one was, whatever its new centre of mass.
    """
    v0, nv = model.mesh_vertadr[i], model.mesh_vertnum[i]
    n0, nn = model.mesh_normaladr[i], model.mesh_normalnum[i]
    f0, nf = model.mesh_faceadr[i], model.mesh_facenum[i]
    rot = np.empty(9)
    mujoco.mju_quat2Mat(rot, model.mesh_quat[i])
    rot = rot.reshape(3, 3)
    mesh = _Mesh(
        verts=model.mesh_vert[v0 : v0 + nv].astype(np.float64) @ rot.T + model.mesh_pos[i],
        faces=model.mesh_face[f0 : f0 + nf].astype(np.int64),
        normals=model.mesh_normal[n0 : n0 + nn].astype(np.float64) @ rot.T,
        face_normals=model.mesh_facenormal[f0 : f0 + nf].astype(np.int64),
    )
    if model.mesh_texcoordnum[i] > 0:
        t0, nt = model.mesh_texcoordadr[i], model.mesh_texcoordnum[i]
        mesh.texcoords = model.mesh_texcoord[t0 : t0 + nt].astype(np.float64)
        mesh.face_texcoords = model.mesh_facetexcoord[f0 : f0 + nf].astype(np.int64)
    return mesh


def _decimated_mesh(model, i: int, elem, settings: FastRenderSettings, out: Path,
                    slack: np.ndarray | None = None) -> Path:
    mesh = _mesh_in_file_frame(model, i)
    slack = np.ones(len(mesh.verts)) if slack is None else np.round(slack, 1)
    src = Path(elem.get("file"))
    key = _key(src.read_bytes() if src.is_file() else str(src), elem.get("scale"), elem.get("refpos"),
               elem.get("refquat"), settings.face_ratio, settings.min_faces, settings.max_area_change, settings.max_deviation, slack.tobytes(), mesh.verts.tobytes()[:4096])
    path = out / f"{src.stem}-{key}.obj"
    if path.is_file():
        return path
    out_mesh = mesh if len(mesh.faces) <= settings.min_faces else _decimate_by_part(mesh, settings, slack)
    _atomic_write(path, _obj_bytes(out_mesh))
    return path


def _decimate_by_part(mesh: _Mesh, settings: FastRenderSettings, slack: np.ndarray) -> _Mesh:
    """Each connected part of the mesh gets the faces it needs, no more.

    A scene mesh is often many parts (a room: walls, a lamp, shelves; a basket: its strands and
    rim). Decimated whole, one fragile part (thin, or finely shaped) decides the budget of all of
    them. Per part, starting at ``face_ratio`` of its faces and doubling until it holds: its area
    within ``max_area_change`` (quadric decimation sometimes eats large flat parts) and 99% of its
    vertices within ``max_deviation`` of the new surface, both scaled by ``slack`` (the per-vertex
    distance factor of static scenery). Parts under ``min_part_faces`` stay whole.
    """
    parts, _ = _parts(mesh)
    order = np.argsort(parts, kind="stable")
    bounds = np.searchsorted(parts[order], np.arange(parts.max() + 2))
    pieces: list[_Mesh] = []
    for p in range(parts.max() + 1):
        faces = order[bounds[p]:bounds[p + 1]]
        sub = _submesh(mesh, faces)
        sub_slack = slack[sub.source_verts]
        area = float(_face_areas(sub).sum())
        target = max(MIN_PART_FACES, int(len(faces) * settings.face_ratio))
        best = sub
        while target < len(faces):
            cand = _simplify(sub, 1.0 - target / len(faces))
            tol_area = sub_slack.min() * settings.max_area_change * area
            if (abs(float(_face_areas(cand).sum()) - area) <= tol_area
                    and np.percentile(_deviation(sub, cand) / sub_slack, 99) <= settings.max_deviation):
                best = cand
                break
            target *= 2
        best.source_faces = faces[best.source_faces] if best is not sub else faces
        pieces.append(best)
    return _concat(mesh, pieces)


MIN_PART_FACES = 24


def _submesh(mesh: _Mesh, faces: np.ndarray) -> _Mesh:
    """The given faces with only the vertices they use (normals and texcoords stay shared)."""
    used, local = np.unique(mesh.faces[faces], return_inverse=True)
    sub = _Mesh(verts=mesh.verts[used], faces=local.reshape(-1, 3), normals=mesh.normals,
                face_normals=mesh.face_normals[faces], texcoords=mesh.texcoords,
                face_texcoords=None if mesh.face_texcoords is None else mesh.face_texcoords[faces],
                source_faces=np.arange(len(faces)))
    sub.source_verts = used
    return sub


def _concat(mesh: _Mesh, pieces: list[_Mesh]) -> _Mesh:
    offsets = np.cumsum([0] + [len(p.verts) for p in pieces])
    return _Mesh(
        verts=np.concatenate([p.verts for p in pieces]),
        faces=np.concatenate([p.faces + o for p, o in zip(pieces, offsets)]),
        normals=mesh.normals,
        face_normals=np.concatenate([p.face_normals for p in pieces]),
        texcoords=mesh.texcoords,
        face_texcoords=None if mesh.face_texcoords is None else np.concatenate([p.face_texcoords for p in pieces]),
        source_faces=np.concatenate([p.source_faces for p in pieces]),
    )


def _deviation(mesh: _Mesh, simple: _Mesh, k: int = 4) -> np.ndarray:
    """How far (metres) each original vertex lies from the decimated surface, approximately:
    the distance to the plane of the closest of the ``k`` decimated faces with the nearest centres.

    Flat regions cost nothing (their vertices lie on the new faces' planes); a woven basket's
    strands or a grille's ribs do, so such meshes keep the faces their shading depends on.
    """
    from scipy.spatial import cKDTree

    tri = simple.verts[simple.faces]
    centres = tri.mean(axis=1)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    k = min(k, len(centres))
    _, near = cKDTree(centres).query(mesh.verts, k=k)
    near = near.reshape(len(mesh.verts), k)
    planes = np.abs(np.einsum("vkj,vkj->vk", mesh.verts[:, None, :] - centres[near], normals[near]))
    return planes.min(axis=1)


def _face_areas(mesh: _Mesh) -> np.ndarray:
    tri = mesh.verts[mesh.faces]
    return np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1) / 2


def _parts(mesh: _Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Connected part of each face (faces sharing a vertex position) and each part's area."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    _, weld = np.unique(np.round(mesh.verts, 5), axis=0, return_inverse=True)
    corners = weld.reshape(-1)[mesh.faces]
    n = int(corners.max()) + 1
    edges = np.concatenate([corners[:, [0, 1]], corners[:, [1, 2]]])
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, vertex_part = connected_components(graph, directed=False)
    parts = vertex_part[corners[:, 0]]
    return parts, np.bincount(parts, weights=_face_areas(mesh))


def _simplify(mesh: _Mesh, reduction: float) -> _Mesh:
    """Quadric decimation of the welded surface; normals and texcoords ride along per corner.

    A surviving face is an original face whose three corners collapsed onto three distinct
    vertices; it keeps its original corners' normals and texcoords, which slide a little
    with the collapse (invisible at 224 px) but keep sharp edges sharp and seams seams.
    """
    import fast_simplification

    # Textured meshes arrive as triangle soup (MuJoCo gives every face corner its own
    # vertex); weld equal positions so the decimator sees one connected surface.
    _, first, weld = np.unique(np.round(mesh.verts, 5), axis=0, return_index=True, return_inverse=True)
    points = mesh.verts[first].astype(np.float32)
    faces = weld.reshape(-1)[mesh.faces]
    _, _, collapses = fast_simplification.simplify(points, faces.astype(np.int32), target_reduction=reduction,
                                                   return_collapses=True)
    new_points, _, mapping = fast_simplification.replay_simplification(points, faces.astype(np.int32), collapses)
    mapped = np.asarray(mapping)[faces]
    keep = (mapped[:, 0] != mapped[:, 1]) & (mapped[:, 1] != mapped[:, 2]) & (mapped[:, 0] != mapped[:, 2])
    _, first = np.unique(np.sort(mapped[keep], axis=1), axis=0, return_index=True)
    rows = np.flatnonzero(keep)[np.sort(first)]
    new_verts = np.asarray(new_points, dtype=np.float64)
    corners = new_verts[mapped[rows]]  # (nk, 3, 3): where each kept corner now sits
    return _Mesh(
        verts=new_verts,
        faces=mapped[rows],
        normals=mesh.normals,
        face_normals=mesh.face_normals[rows],
        texcoords=mesh.texcoords,
        face_texcoords=None if mesh.face_texcoords is None else _rewire(
            mesh.verts, mesh.faces, mesh.texcoords, mesh.face_texcoords, rows, corners),
        source_faces=rows,
    )


def _rewire(verts, faces, values, face_values, rows, corners) -> np.ndarray:
    """Per-corner attribute indices (texcoords or normals) for the kept faces' moved corners.

    A collapse moves a vertex but leaves each surviving face with its original corners'
    texture coordinates, so labels and wood grain slide across the surface. Instead, each
    moved corner takes the attribute of the nearest original corner *in the same chart*: the
    region of faces over which the attribute is continuous (faces joined by a corner with the
    same position and the same value). Staying inside the chart keeps seams (u=0 next to u=1
    on a can's label, a sharp edge's two normals) from bleeding into each other.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    nf = len(faces)
    pos = np.round(verts[faces].reshape(-1, 3), 5)
    val = np.round(values[face_values].reshape(-1, values.shape[1]), 4)
    _, key = np.unique(np.concatenate([pos, val], axis=1), axis=0, return_inverse=True)
    key = key.reshape(-1)
    face_of = np.repeat(np.arange(nf), 3)
    # faces and corner keys as one bipartite graph: a chart is a connected component of it
    n = nf + int(key.max()) + 1
    graph = coo_matrix((np.ones(len(key)), (face_of, nf + key)), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    chart = comp[:nf]
    corner_chart = chart[face_of]
    corner_pos = verts[faces].reshape(-1, 3)
    corner_val = face_values.reshape(-1)
    out = np.empty((len(rows), 3), dtype=np.int64)
    kept_chart = chart[rows]
    order = np.argsort(corner_chart, kind="stable")
    bounds = np.searchsorted(corner_chart[order], np.arange(chart.max() + 2))
    for c in np.unique(kept_chart):
        members = order[bounds[c]:bounds[c + 1]]
        sel = np.flatnonzero(kept_chart == c)
        _, nearest = cKDTree(corner_pos[members]).query(corners[sel].reshape(-1, 3))
        out[sel] = corner_val[members[nearest]].reshape(-1, 3)
    return out


def _obj_bytes(mesh: _Mesh) -> bytes:
    lines = [f"v {x:.7g} {y:.7g} {z:.7g}" for x, y, z in mesh.verts]
    lines += [f"vn {x:.6g} {y:.6g} {z:.6g}" for x, y, z in mesh.normals]
    if mesh.texcoords is not None:
        # MuJoCo flips v when it reads OBJ texcoords; flip back so the round trip is identity.
        lines += [f"vt {u:.7g} {1.0 - v:.7g}" for u, v in mesh.texcoords]
        for f, t, n in zip(mesh.faces + 1, mesh.face_texcoords + 1, mesh.face_normals + 1):
            lines.append(f"f {f[0]}/{t[0]}/{n[0]} {f[1]}/{t[1]}/{n[1]} {f[2]}/{t[2]}/{n[2]}")
    else:
        for f, n in zip(mesh.faces + 1, mesh.face_normals + 1):
            lines.append(f"f {f[0]}//{n[0]} {f[1]}//{n[1]} {f[2]}//{n[2]}")
    return ("\n".join(lines) + "\n").encode()


def _small_texture(src: Path, max_side: int, out: Path) -> Path:
    from PIL import Image

    key = _key(src.read_bytes(), max_side)
    path = out / f"{src.stem}-{key}.png"
    if path.is_file():
        return path
    with Image.open(src) as img:
        if img.mode not in ("RGB", "RGBA", "L", "LA"):  # e.g. the kitchen fridge's palette PNG: reduce() needs pixels
            img = img.convert("RGBA" if "transparency" in img.info else "RGB")
        # Power-of-two factors keep cube-map faces (e.g. 512x3072 = 1x6 squares) divisible.
        factor = 1
        while max(img.size) // factor > max_side:
            factor *= 2
        img = img.reduce(factor) if factor > 1 else img.copy()
        tmp = path.with_suffix(f".{os.getpid()}.png")
        img.save(tmp)
    os.replace(tmp, path)
    return path
