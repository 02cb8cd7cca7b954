"""`seal bench serve`: what a policy server on loopback costs per chunk round trip.

The scripted expert acts on one real LIBERO observation (both camera images included, so the
payload is what a VLA server receives) in three ways: in process, and through `seal serve` in
a child process with K observations sent batched, over K concurrent sockets, or one by one.
Times are medians over ``--trials`` rounds in which every variant runs once, in turn (after two
warm-up calls each); the overhead is the best K-candidate remote round trip over the
in-process call doing the same work.
"""

from __future__ import annotations

import statistics
import time

import numpy as np
from openpi_client import msgpack_numpy


def _interleaved_ms(calls: dict, reps: int) -> dict:
    """Median ms per named call; the calls take turns, so load from other processes on a shared
    machine falls on all of them alike instead of on whichever happened to run last."""
    for fn in calls.values():  # warm-up: connections, first-call allocations
        fn(), fn()
    times: dict = {name: [] for name in calls}
    for _ in range(reps):
        for name, fn in calls.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {name: round(statistics.median(t) * 1e3, 3) for name, t in times.items()}


def run(args) -> dict:
    from rich.console import Console

    from seal.policies import make_policy
    from seal.serving import protocol as P
    from seal.serving.client import ClientConfig, OpenpiPolicy
    from seal.serving.server import ServerProcess
    from seal.sim.suites import get_task
    from seal.sim.world import LiberoWorld
    from seal.steer.method import MethodSpec

    from seal.benchmarks.common import trials_of

    k, reps = args.k, max(5, min(trials_of(args, "serve"), 200))
    spec = get_task(args.suite, args.task)
    console = Console(stderr=True)
    expert = make_policy("scripted", MethodSpec(knobs="misaligned"), spec)
    with console.status(f"building {spec.key} for one observation"):
        world = LiberoWorld(spec)
        try:
            world.reset(0)
            obs = world.observe(images=True, privileged_atoms=expert.privileged_atoms())
        finally:
            world.close()
    rows = list(range(k))
    expert.reset(spec.instruction, seed=0)
    reasoning = expert.reason(obs)
    # the same calls the server makes (a reply to reason() carries actions of a fresh attempt),
    # so both sides draw the same attempts and do the same work
    expert.begin(1)
    expert.begin(k)
    out: dict = {"task": spec.key, "k": k, "trials": reps}
    request = P.observation_request(obs, info=P.ServerInfo(privileged=True))
    out["request_kb_per_obs"] = round(len(msgpack_numpy.packb(request)) / 1024, 1)
    out["scene_kb_per_obs"] = round(len(msgpack_numpy.packb(request[P.SCENE])) / 1024, 1)

    with console.status("starting seal serve on loopback"):
        server = ServerProcess(["--knobs", "misaligned"]).__enter__()
    policies = {}
    try:
        for transport in ("sequential", "concurrent", "batched"):
            policy = policies[transport] = OpenpiPolicy(ClientConfig(port=server.port, transport=transport),
                                                        task=spec.key)
            policy.reset(spec.instruction, seed=0)
            policy.reason(obs)
            policy.begin(k)
        calls = {
            "inprocess_ms_k1": lambda: expert.act([obs], reasoning, rows=[0]),
            f"inprocess_ms_k{k}": lambda: expert.act([obs] * k, reasoning, rows=rows),
            "rtt_ms_k1": lambda: policies["sequential"].act([obs], reasoning, rows=[0]),
            **{f"rtt_ms_k{k}_{t}": (lambda p=p: p.act([obs] * k, reasoning, rows=rows)) for t, p in policies.items()},
        }
        with console.status(f"{reps} rounds of {len(calls)} calls, taking turns (K={k})"):
            out.update(_interleaved_ms(calls, reps))
    finally:
        for policy in policies.values():
            policy.close()
        server.__exit__(None, None, None)
    remote = {t: out[f"rtt_ms_k{k}_{t}"] for t in ("concurrent", "batched")}
    out["faster"] = min(remote, key=remote.get)
    out["overhead_vs_inprocess"] = round(min(remote.values()) / out[f"inprocess_ms_k{k}"], 2)
    out["overhead_ms_per_chunk"] = round(min(remote.values()) - out[f"inprocess_ms_k{k}"], 3)
    out["numpy"] = np.__version__
    return out
