"""`seal bench sim`: physics step, exact restore, stock vs fast rendering, pool speedup."""

from __future__ import annotations

import time

import numpy as np

from seal.sim.observation import AGENT_CAMERA, RENDER_SIZE, to_policy_image
from seal.sim.pool import EnvPool
from seal.sim.world import LiberoWorld


def _median_ms(fn, n: int) -> float:
    times = []
    for _ in range(n):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return round(1000 * float(np.median(times)), 3)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else round(10 * np.log10(255.0**2 / mse), 2)


def _states(world: LiberoWorld, rng, n: int) -> list:
    """A few varied states: official inits, and the same after some random motion."""
    out = []
    for i in range(n):
        world.reset(i)
        out.append(world.snapshot())
        world.step_chunk(rng.uniform(-1, 1, (20, 7)))
        out.append(world.snapshot())
    return out


def run(args) -> dict:
    task = (args.suite, args.task)
    rng = np.random.default_rng(0)
    world = LiberoWorld(task, render_mode="stock")
    world.reset(0)
    actions = rng.uniform(-1, 1, (60, 7))

    # physics: one 20 Hz control step (25 MuJoCo substeps), cameras off
    it = iter(actions)
    physics_ms = _median_ms(lambda: world.step(next(it)), 40)

    # exact restore: snapshot, run 50 steps, restore, replay, compare bit for bit
    world.reset(1)
    snap = world.snapshot()
    world.step_chunk(actions[:50])
    reference = world.snapshot()
    world.reset(2)
    restore_ms = _median_ms(lambda: world.restore(snap), 50)
    world.restore(snap)
    world.step_chunk(actions[:50])
    diff = float(np.abs(world.snapshot().physics - reference.physics).max())

    # rendering: the same states drawn by the stock and the fast render model
    fast = LiberoWorld(task, render_mode="fast")
    states = _states(world, rng, 3)
    raw_psnr, policy_psnr = [], []
    for s in states:
        world.restore(s)
        fast.restore(s)
        a = world.render_raw((AGENT_CAMERA,))[AGENT_CAMERA]
        b = fast.render_raw((AGENT_CAMERA,))[AGENT_CAMERA]
        raw_psnr.append(psnr(a, b))
        policy_psnr.append(psnr(to_policy_image(a), to_policy_image(b)))
    render_stock = _median_ms(lambda: world.render_raw((AGENT_CAMERA,)), 10)
    render_fast = _median_ms(lambda: fast.render_raw((AGENT_CAMERA,)), 10)
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

    serial_ms = _median_ms(serial, rounds)
    world.close()
    with EnvPool(task, k=k, workers=args.workers) as pool:
        pool.sync(start_snap)
        pool.step(chunks)  # warm-up
        pool_ms = _median_ms(lambda: (pool.sync(start_snap), pool.step(chunks)), rounds)
        workers = pool.num_workers

    return {
        "task": f"{args.suite}/{args.task}",
        "physics_step_ms": physics_ms,
        "restore_ms": restore_ms,
        "restore_max_abs_diff": diff,
        "render_size": RENDER_SIZE,
        "render_ms_stock": render_stock,
        "render_ms_fast": render_fast,
        "render_fast_speedup": round(render_stock / render_fast, 2),
        "render_fast_psnr": round(float(np.median(raw_psnr)), 2),
        "render_fast_psnr_policy_224": round(float(np.median(policy_psnr)), 2),
        "pool_k": k,
        "pool_workers": workers,
        "pool_chunk_ms": pool_ms,
        "serial_chunk_ms": serial_ms,
        "pool_speedup": round(serial_ms / pool_ms, 2),
    }
