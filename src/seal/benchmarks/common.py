"""What the benchmarks share: median timings and ``--trials`` defaults."""

from __future__ import annotations

# `--trials` when not given, per benchmark (what it counts differs: init states per task, trials of
# the eval harness, round trips of `serve`). A value given is always honoured, never replaced.
DEFAULT_TRIALS = {"expert": 50, "steer": 50, "runtime": 50, "eval": 3, "serve": 50, "verifier-sweep": 10, "labels": 1}


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
