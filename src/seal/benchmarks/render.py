"""`seal bench render`: the fast render mode per task and camera at one size - quality against
stock, time per camera, and *where* the error is.

``ms_fast_no_msaa`` / ``psnr_fast_no_msaa``: the same fast frame without MuJoCo's 4x multisampling
(stock images have it), so the share of the time that anti-aliasing takes, and the quality it
buys, stand beside each other.

``--budgets 3,6``: the fast model rebuilt with its mesh tolerances (deviation and area) that many
times looser, the budget a 64-px view might afford (issue 33): faces, PSNR against stock, and time
per camera *timed interleaved with the shipped fast model* on the same state (``ms_ratio``: its
time over the shipped model's), with and without multisampling. Comparing renderers one after
another on a shared machine measures the load; taking turns frame by frame measures the renderers.

The error of a fast frame is attributed to the geoms that stock draws at each pixel (MuJoCo's
segmentation render of the stock model): the share of the squared error each mesh carries says
which mesh to fix next, and whether it is texture or geometry. One state per task: the episode
start of init 0 after 20 seeded random actions (the arm in view, objects where LIBERO put them).
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np

from seal.benchmarks.common import median_ms
from seal.benchmarks.sim import psnr
from seal.errors import InvalidInput
from seal.sim.observation import AGENT_CAMERA, WRIST_CAMERA
from seal.sim.render import SceneRenderer, drawn_faces, scene_option
from seal.sim.suites import get_task, parse_task_ids
from seal.sim.world import LiberoWorld

TOP = 4  # geoms listed per camera


def _segmentation(world: LiberoWorld, camera: str, px: int) -> np.ndarray:
    """Geom id per pixel of the stock image (-1: background)."""
    model = world.model
    data = mujoco.MjData(model)
    data.qpos[:] = world.render_state()
    mujoco.mj_kinematics(model, data)
    mujoco.mj_camlight(model, data)
    renderer = mujoco.Renderer(model, px, px)
    try:
        renderer.enable_segmentation_rendering()
        renderer.update_scene(data, camera=camera, scene_option=scene_option())
        return renderer.render()[..., 0]
    finally:
        renderer.close()


def _geom_label(model: mujoco.MjModel, g: int) -> str:
    if g < 0:
        return "background"
    if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_MESH, model.geom_dataid[g])
    else:
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
    return name or f"geom {g}"


def _fixed_cost_ms(world: LiberoWorld, px: int) -> float:
    """A frame with every geom hidden: clearing, skybox, lights and read-back, what no mesh
    budget can save."""
    option = scene_option()
    for group in range(len(option.geomgroup)):
        option.geomgroup[group] = 0
    renderer = SceneRenderer(world.render_model, px, option=option)
    try:
        return median_ms(lambda: renderer.render(world.model, world.data, AGENT_CAMERA, world.render_state()), 8)
    finally:
        renderer.close()


def _no_msaa_renderer(world: LiberoWorld, px: int) -> SceneRenderer:
    """The fast render model without multisampling (MuJoCo's offscreen default is 4 samples per
    pixel, which stock LIBERO images have): what the anti-aliasing costs, and what it is worth."""
    model = copy.deepcopy(world.render_model)
    model.vis.quality.offsamples = 0
    return SceneRenderer(model, px)


def _one_task(spec, px: int) -> dict:
    stock = LiberoWorld(spec, render_mode="stock")
    fast = LiberoWorld(spec, render_mode="fast")
    closing: list[SceneRenderer] = []
    try:
        actions = np.random.default_rng(0).uniform(-1, 1, (20, 7))
        for w in (stock, fast):
            w.reset(0)
            w.step_chunk(actions)
        out = {"faces_stock": drawn_faces(stock.model), "faces_fast": drawn_faces(fast.render_model),
               "ms_fixed": _fixed_cost_ms(fast, px)}
        no_msaa = _no_msaa_renderer(fast, px)
        closing.append(no_msaa)
        for camera, name in ((AGENT_CAMERA, "agent"), (WRIST_CAMERA, "wrist")):
            a = stock.render_raw((camera,), size=px)[camera]
            b = fast.render_raw((camera,), size=px)[camera]
            plain = lambda: no_msaa.render(fast.model, fast.data, camera, fast.render_state())  # noqa: E731
            err = ((a.astype(np.float64) - b.astype(np.float64)) ** 2).sum(-1)
            ids = _segmentation(stock, camera, px)
            total = float(err.sum()) or 1.0
            shares = sorted(((float(err[ids == g].sum()) / total, int(g)) for g in np.unique(ids)), reverse=True)
            out[name] = {
                "psnr": psnr(a, b),
                "ms_stock": median_ms(lambda: stock.render_raw((camera,), size=px), 8),
                "ms_fast": median_ms(lambda: fast.render_raw((camera,), size=px), 8),
                "psnr_fast_no_msaa": psnr(a, plain()),
                "ms_fast_no_msaa": median_ms(plain, 8),
                "error_by_geom": [{"geom": _geom_label(stock.model, g), "share": round(s, 3)}
                                  for s, g in shares[:TOP]],
            }
        return out
    finally:
        for renderer in closing:
            renderer.close()
        stock.close()
        fast.close()


def _budget_rows(spec, px: int, factors: list[float], rounds: int = 15) -> list[dict]:
    """Looser mesh budgets against the shipped fast model, timed taking turns (see the module doc)."""
    import time

    from seal.sim.fast_assets import FastRenderSettings, build_fast_model

    stock = LiberoWorld(spec, render_mode="stock")
    fast = LiberoWorld(spec, render_mode="fast")
    renderers: dict[tuple[float, int], SceneRenderer] = {}
    try:
        actions = np.random.default_rng(0).uniform(-1, 1, (20, 7))
        for w in (stock, fast):
            w.reset(0)
            w.step_chunk(actions)
        base = FastRenderSettings()
        xml = fast.scene_xml()
        models = {1.0: fast.render_model}
        for f in factors:
            models[f] = build_fast_model(xml, FastRenderSettings(max_deviation=base.max_deviation * f,
                                                                 max_area_change=base.max_area_change * f))
        for f, model in models.items():
            for samples in (model.vis.quality.offsamples, 0):
                m = copy.deepcopy(model)
                m.vis.quality.offsamples = samples
                renderers[f, samples] = SceneRenderer(m, px)
        cameras = ((AGENT_CAMERA, "agent"), (WRIST_CAMERA, "wrist"))
        times = {key: {c: [] for c, _ in cameras} for key in renderers}
        state = fast.render_state()
        for _ in range(rounds):
            for key, r in renderers.items():
                for camera, _ in cameras:
                    t0 = time.perf_counter()
                    r.render(fast.model, fast.data, camera, state)
                    times[key][camera].append(time.perf_counter() - t0)
        ref = {camera: stock.render_raw((camera,), size=px)[camera] for camera, _ in cameras}
        msaa = fast.render_model.vis.quality.offsamples
        rows = []
        for (f, samples), r in renderers.items():
            row = {"tolerance_x": f, "multisampling": samples > 0, "faces": drawn_faces(r.model)}
            for camera, name in cameras:
                ms = 1000 * float(np.median(times[f, samples][camera]))
                shipped = 1000 * float(np.median(times[1.0, msaa][camera]))
                row[name] = {"psnr": psnr(ref[camera], r.render(fast.model, fast.data, camera, state)),
                             "ms": round(ms, 2), "ms_ratio": round(ms / shipped, 3)}
            rows.append(row)
        return rows
    finally:
        for r in renderers.values():
            r.close()
        stock.close()
        fast.close()


def run(args) -> dict:
    px = getattr(args, "image_size", None) or 64
    if not 16 <= px <= 1024:
        raise InvalidInput(f"--image-size must be in 16..1024, got {px}")
    tasks = parse_task_ids(args.suite, args.tasks or "0,3,9")
    factors = []
    for text in filter(None, (t.strip() for t in (getattr(args, "budgets", None) or "").split(","))):
        try:
            factors.append(float(text))
        except ValueError:
            factors.append(float("nan"))
        if not factors[-1] > 1.0:
            raise InvalidInput(f"--budgets takes tolerance factors above 1 (how many times looser than the shipped "
                               f"fast model's), e.g. 3,6; got {text!r}")
    if factors:
        return {"suite": args.suite, "px": px, "state": "init 0 after 20 seeded random actions",
                "budgets": {str(t): _budget_rows(get_task(args.suite, t), px, factors) for t in tasks}}
    return {"suite": args.suite, "px": px,
            "state": "init 0 after 20 seeded random actions",
            "tasks": {str(t): _one_task(get_task(args.suite, t), px) for t in tasks}}
