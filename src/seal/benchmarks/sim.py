"""`seal bench sim`: physics step (robosuite's and the fast one side by side), exact restore,
observations against the package's own camera path, stock vs fast rendering per resolution, pool
speedup."""

from __future__ import annotations

import time

import numpy as np

from seal.benchmarks.common import median_ms
from seal.sim.observation import AGENT_CAMERA, IMAGE_SIZE, RENDER_SIZE, WRIST_CAMERA, to_policy_image
from seal.sim.package_path import package_frames
from seal.sim.pool import EnvPool
from seal.sim.render import drawn_faces
from seal.sim.world import LiberoWorld


def psnr(a: np.ndarray, b: np.ndarray) -> float | None:
    """PSNR in dB; None for identical images (infinite PSNR has no JSON spelling)."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return None if mse == 0 else round(10 * np.log10(255.0**2 / mse), 2)


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean SSIM of two uint8 RGB images (Gaussian window, sigma 1.5, as Wang et al. 2004)."""
    from scipy.ndimage import gaussian_filter

    x, y = a.astype(np.float64), b.astype(np.float64)
    blur = lambda im: gaussian_filter(im, sigma=(1.5, 1.5, 0), truncate=3.5)  # noqa: E731
    mx, my = blur(x), blur(y)
    vx, vy, cov = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    s = ((2 * mx * my + c1) * (2 * cov + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return round(float(s.mean()), 4)


def _consumed(world: LiberoWorld, px: int, camera: str = AGENT_CAMERA) -> np.ndarray:
    """A view as a consumer at ``px`` gets it: openpi's 256 -> 224 path at 224, else a render at
    that size."""
    if px == IMAGE_SIZE:
        return to_policy_image(world.render_raw((camera,))[camera])
    return world.render_raw((camera,), size=px)[camera]


def _vs_package(world: LiberoWorld) -> dict:
    """Our episode-0 observation against the package's, same state, both cameras at 224."""
    world.reset(0)
    ours = world.observe()
    theirs = package_frames(world.task, 0, camera_pose=world.camera_pose)[0]
    out = {}
    for view in ("agent", "wrist"):
        a, b = getattr(ours, view), getattr(theirs, view)
        out[f"obs_psnr_vs_package_{view}"] = psnr(a, b)
        out[f"obs_max_abs_diff_vs_package_{view}"] = int(np.abs(a.astype(np.int16) - b).max())
    out["obs_state_max_abs_diff_vs_package"] = float(np.abs(ours.state - theirs.state).max())
    return out


def _states(world: LiberoWorld, rng, n: int) -> list:
    """A few varied states: official inits, and the same after some random motion."""
    out = []
    for i in range(n):
        world.reset(i)
        out.append(world.snapshot())
        world.step_chunk(rng.uniform(-1, 1, (20, 7)))
        out.append(world.snapshot())
    return out


def _control_steps(world: LiberoWorld, actions: np.ndarray, rounds: int = 8) -> dict:
    """One 20 Hz control step through robosuite's ``env.step`` and through `seal.sim.fast_step`,
    measured side by side: the same start and actions in every round, the two taking turns at
    going first, median of every step's time. Whether each round ends in the same snapshot (bit
    for bit) is reported with it."""
    start, default = world.snapshot(), world.fast_step
    times: dict[bool, list[float]] = {False: [], True: []}
    identical = True
    for r in range(rounds):
        ends = {}
        for fast in ((False, True) if r % 2 == 0 else (True, False)):
            world.restore(start)
            world.fast_step = fast
            for a in actions:
                t0 = time.perf_counter()
                world.step(a)
                times[fast].append(time.perf_counter() - t0)
            ends[fast] = world.snapshot()
        identical &= ends[False] == ends[True]
    world.fast_step = default
    stock, fast = (float(np.median(times[f])) * 1e3 for f in (False, True))
    return {
        "control_step_ms_stock": round(stock, 3),
        "control_step_ms_fast": round(fast, 3),
        "control_step_speedup": round(stock / fast, 2),
        "control_step_identical": bool(identical),
        "control_step_fast_unsupported": world.fast_step_unsupported or None,
    }


RENDER_SIZES = (64, 96, 128, IMAGE_SIZE)  # policy resolutions to choose from, and the verifier's


def run(args) -> dict:
    task = (args.suite, args.task)
    rng = np.random.default_rng(0)
    world = LiberoWorld(task, render_mode="stock")
    world.reset(0)
    actions = rng.uniform(-1, 1, (60, 7))

    # reset: openpi's episode start (fixtures, controller), an init state not used before, settle steps
    episodes = iter(range(1, world.num_init_states))
    reset_ms = median_ms(lambda: world.reset(next(episodes)), 8)
    world.reset(0)

    # physics: one 20 Hz control step (25 MuJoCo substeps), cameras off, the world's default step
    it = iter(actions)
    physics_ms = median_ms(lambda: world.step(next(it)), 40)
    # and robosuite's step against the fast one, interleaved from the state reached
    control = _control_steps(world, actions[40:60])

    # exact restore: snapshot, run 50 steps, restore, replay, compare bit for bit
    world.reset(1)
    snap = world.snapshot()
    world.step_chunk(actions[:50])
    reference = world.snapshot()
    world.reset(2)
    restore_ms = median_ms(lambda: world.restore(snap), 50)
    world.restore(snap)
    world.step_chunk(actions[:50])
    diff = float(np.abs(world.snapshot().physics - reference.physics).max())

    # observations: the same episode start through the package's own camera path
    package = _vs_package(world)

    # rendering: the same states drawn by the stock and the fast render model, at each size a
    # consumer uses (policy 64-128, verifier 224), compared at that size
    fast = LiberoWorld(task, render_mode="fast")
    states = _states(world, rng, 3)
    sizes = {}
    for px in RENDER_SIZES:
        for camera, suffix in ((AGENT_CAMERA, ""), (WRIST_CAMERA, "_wrist")):
            quality = []
            for s in states:
                world.restore(s)
                fast.restore(s)
                a, b = _consumed(world, px, camera), _consumed(fast, px, camera)
                quality.append((psnr(a, b), ssim(a, b)))
            sizes[f"render_ms_stock_{px}{suffix}"] = median_ms(lambda: _consumed(world, px, camera), 10)
            sizes[f"render_ms_fast_{px}{suffix}"] = median_ms(lambda: _consumed(fast, px, camera), 10)
            sizes[f"render_psnr_fast_{px}{suffix}"] = round(float(np.median([q[0] or np.inf for q in quality])), 2)
            sizes[f"render_ssim_fast_{px}{suffix}"] = round(float(np.median([q[1] for q in quality])), 4)
    sizes["faces_stock"] = drawn_faces(world.model)  # faces a camera draws (collision meshes excluded)
    sizes["faces_fast"] = drawn_faces(fast.render_model)
    world.restore(states[0])
    fast.restore(states[0])
    render_stock = median_ms(lambda: world.render_raw((AGENT_CAMERA,)), 10)
    render_fast = median_ms(lambda: fast.render_raw((AGENT_CAMERA,)), 10)
    render_both = median_ms(lambda: world.render_raw((AGENT_CAMERA, WRIST_CAMERA)), 5)
    fast.close()

    # pool: K envs stepping 5-step chunks, vs the same work in this one process
    k = args.k
    chunks = [rng.uniform(-1, 1, (5, 7)) for _ in range(k)]
    start_snap = world.snapshot()
    rounds = 3

    def serial():
        for c in chunks:
            world.restore(start_snap)
            world.step_chunk(c)

    serial_ms = median_ms(serial, rounds)
    world.close()
    with EnvPool(task, k=k, workers=args.workers) as pool:
        pool.sync(start_snap)
        pool.step(chunks)  # warm-up
        pool_ms = median_ms(lambda: (pool.sync(start_snap), pool.step(chunks)), rounds)
        workers = pool.num_workers

    return {
        "task": f"{args.suite}/{args.task}",
        "reset_ms": reset_ms,
        "physics_step_ms": physics_ms,
        **control,
        "restore_ms": restore_ms,
        "restore_max_abs_diff": diff,
        **package,
        "render_size": RENDER_SIZE,
        "render_ms_stock": render_stock,
        "render_ms_fast": render_fast,
        "render_ms_stock_both_cameras": render_both,
        "render_fast_speedup": round(render_stock / render_fast, 2),
        **sizes,
        "pool_k": k,
        "pool_workers": workers,
        "pool_chunk_ms": pool_ms,
        "serial_chunk_ms": serial_ms,
        "pool_speedup": round(serial_ms / pool_ms, 2),
    }
