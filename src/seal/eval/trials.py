"""What an evaluation run is made of: method configurations and the trials they run.

A *method* is a `seal.steer.method.MethodSpec`: a steering method plus every setting that
changes its results (K, rounds, verifier, policy, mismatch...). Its config hash names it in the
results store, so two runs of "seal" with different K never mix, and re-running the same command
finds its own finished trials.

A *trial* is (suite, task, trial number). Its init state and seed depend only on those, never on
the method, so every method is compared on the same starts (paired comparisons in reports).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

from seal.errors import InvalidInput
# One method description for every command: defined with the steering loop, re-exported here.
from seal.steer.method import MethodSpec, parse_methods  # noqa: F401


@dataclass(frozen=True)
class TrialSpec:
    """One episode to run: a method on (suite, task, trial)."""

    method: MethodSpec
    suite: str
    task: int
    trial: int
    init_index: int
    seed: int

    @property
    def key(self) -> tuple[str, str, int, int]:
        return (self.method.config_hash, self.suite, self.task, self.trial)

    @property
    def name(self) -> str:
        return f"{self.method.label} {self.suite}/{self.task} #{self.trial}"


def trial_seed(suite: str, task: int, trial: int) -> int:
    """Same for every method; stable across Python runs (no hash randomisation)."""
    return int.from_bytes(hashlib.sha1(f"{suite}/{task}/{trial}".encode()).digest()[:4], "little")


def expand(methods: list[MethodSpec], suites: list[str], tasks: list[int] | None, trials: int) -> list[TrialSpec]:
    """Every (method, suite, task, trial), ordered so one task's trials run together (env pools
    are reused across them) and methods alternate (a run stopped early stays balanced)."""
    from seal.sim.suites import get_task, task_count

    if trials < 1:
        raise InvalidInput(f"--trials must be >= 1, got {trials}")
    out = []
    for suite in suites:
        n = task_count(suite)
        ids = list(range(n)) if tasks is None else tasks
        for task in ids:
            inits = len(get_task(suite, task).init_states())
            for trial in range(trials):
                for m in methods:
                    out.append(TrialSpec(m, suite, task, trial, init_index=trial % inits,
                                         seed=trial_seed(suite, task, trial)))
    return out
