"""Benchmarks: each is a function of parsed CLI arguments that returns one JSON-able dict.

Timings are medians of several repetitions; comparisons (speedups) are ratios taken within one
run, because this kind of machine is shared and noisy.
"""

from __future__ import annotations

import importlib

BENCHMARKS = {"sim": "seal.benchmarks.sim:run", "expert": "seal.benchmarks.expert:run",
              "steer": "seal.benchmarks.steer:run_steer", "runtime": "seal.benchmarks.steer:run_runtime",
              "eval": "seal.benchmarks.eval:run",
              "serve": "seal.benchmarks.serve:run",
              "annotate": "seal.benchmarks.annotate:run",
              "value": "seal.benchmarks.value:run",
              "verifier": "seal.benchmarks.verifier:run",
              "verifier-sweep": "seal.benchmarks.sweep:run",
              "vla": "seal.benchmarks.vla:run",
              "render": "seal.benchmarks.render:run"}


# `--trials` when not given, per benchmark (what it counts differs: init states per task, trials of
# the eval harness, round trips of `serve`). A value given is always honoured, never replaced.
DEFAULT_TRIALS = {"expert": 50, "steer": 50, "runtime": 50, "eval": 3, "serve": 50, "verifier-sweep": 10}


def median_ms(fn, n: int, *, warmup: bool = False) -> float:
    """Median wall time of ``n`` calls of ``fn``, in ms (after one untimed call with ``warmup``:
    allocators, lazy initialisation)."""
    import time

    import numpy as np

    if warmup:
        fn()
    times = []
    for _ in range(n):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return round(1000 * float(np.median(times)), 3)


def trials_of(args, name: str) -> int:
    """``--trials`` as given, else this benchmark's default; refuses a count below 1."""
    from seal.errors import InvalidInput

    n = getattr(args, "trials", None)
    n = DEFAULT_TRIALS[name] if n is None else int(n)
    if n < 1:
        raise InvalidInput(f"--trials must be >= 1, got {n}")
    return n


def run_benchmark(name: str, args) -> dict:
    if name not in BENCHMARKS:
        from seal.errors import InvalidInput

        raise InvalidInput(f"unknown benchmark {name!r}; valid: {', '.join(BENCHMARKS)}")
    module, func = BENCHMARKS[name].split(":")
    return getattr(importlib.import_module(module), func)(args)
