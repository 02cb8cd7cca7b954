"""Benchmarks: each is a function of parsed CLI arguments that returns one JSON-able dict.

Timings are medians of several repetitions; comparisons (speedups) are ratios taken within one
run, because this kind of machine is shared and noisy. `BENCHMARKS` names each benchmark's
function by a dotted path (imported when run); what they share is in `common`.
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
              "render": "seal.benchmarks.render:run",
              "labels": "seal.benchmarks.labels:run",
              "grasp": "seal.benchmarks.grasp:run"}


def run_benchmark(name: str, args) -> dict:
    if name not in BENCHMARKS:
        from seal.errors import InvalidInput

        raise InvalidInput(f"unknown benchmark {name!r}; valid: {', '.join(BENCHMARKS)}")
    module, func = BENCHMARKS[name].split(":")
    return getattr(importlib.import_module(module), func)(args)
