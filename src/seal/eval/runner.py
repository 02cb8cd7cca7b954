"""`seal eval`: methods x suites x tasks x trials into the results store, resumable.

The run is the set of trial keys the command describes; the store holds the finished ones.
Re-running the same command therefore runs exactly what is missing. Rows are committed one by
one as trials finish, so Ctrl-C or a crash loses only the trials in flight.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field, replace
from typing import Callable

from seal.errors import InvalidInput, VerifierUnavailable
from seal.eval.backends import BACKENDS, make_backend
from seal.eval.execute import RunOptions
from seal.eval.store import ResultStore, TrialRow
from seal.eval.trials import MethodSpec, TrialSpec, expand


@dataclass
class EvalSummary:
    db: str
    planned: int = 0
    already_done: int = 0
    ran: int = 0
    errors: int = 0
    success: dict = field(default_factory=dict)  # method label -> fraction over this command's trials
    trials: dict = field(default_factory=dict)  # method label -> finished trials of this command
    verifier_errors: dict = field(default_factory=dict)  # method label -> verifications with no answer
    verifier_unavailable: dict = field(default_factory=dict)  # method label -> trials mostly unverified
    # method label -> share of committed sub-plans achieved by simulator truth (None: none audited)
    alignment: dict = field(default_factory=dict)


def plan_eval(store: ResultStore, methods: list[MethodSpec], suites: list[str], tasks: list[int] | None,
              trials: int, retry_errors: bool = False) -> tuple[list[TrialSpec], list[TrialSpec]]:
    """(all trials of the command, the ones still to run; with ``retry_errors``, trials stored as
    errors run again)."""
    return _todo(store, expand(methods, suites, tasks, trials), retry_errors)


def _todo(store: ResultStore, every: list[TrialSpec], retry_errors: bool) -> tuple[list[TrialSpec], list[TrialSpec]]:
    done = store.done_keys(errors=not retry_errors)
    return every, [t for t in every if t.key not in done]


def run_eval(db: str, methods: list[MethodSpec], suites: list[str], tasks: list[int] | None, trials: int, *,
             options: RunOptions, backend: str = "local", workers: int = 1, address: str | None = None,
             on_row: Callable[[TrialRow, int, int], None] | None = None, retry_errors: bool = False) -> EvalSummary:
    # Everything the arguments decide is checked before the store is opened: a refused command
    # leaves no database behind.
    every = expand(methods, suites, tasks, trials)
    if backend not in BACKENDS:
        raise InvalidInput(f"unknown backend {backend!r}; valid: {', '.join(BACKENDS)}")
    for name, value in (("--workers", workers), ("--pool-workers", options.pool_workers)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise InvalidInput(f"{name} must be an integer >= 1, got {value!r}")
    if options.max_steps is not None and (not isinstance(options.max_steps, int) or options.max_steps < 1):
        raise InvalidInput(f"--max-steps must be an integer >= 1 (or left out: the suite's limit), "
                           f"got {options.max_steps!r}")
    with ResultStore(db) as store:
        store.check_step_cap(options.max_steps)
        every, todo = _todo(store, every, retry_errors)
        for m in methods:
            store.register_method(m.config_hash, m.label, m.canonical())
        summary = EvalSummary(db=str(db), planned=len(every), already_done=len(every) - len(todo))
        options = replace(options, pool_k=max(m.effective_k for m in methods))
        runner = make_backend(backend, options, workers, address) if todo else None
        try:
            for row in (runner.run(todo) if runner else ()):
                if row.fatal:  # not stored: once the verifier is fixed, re-running the command redoes it
                    raise VerifierUnavailable(
                        f"stopped the run: {row.fatal} (in {row.method} {row.suite}/{row.task} trial {row.trial}; "
                        f"{summary.ran} trial(s) of this command were stored, re-run the same command to resume)")
                store.add(row, replace_error=retry_errors)
                summary.ran += 1
                summary.errors += row.status == "error"
                if on_row:
                    on_row(row, summary.ran, len(todo))
        finally:
            if runner is not None and hasattr(runner, "shutdown"):
                runner.shutdown()
        keys = {t.key for t in every}
        per = defaultdict(list)
        for row in store.rows():
            if row.key in keys:
                per[row.method].append(row)
        summary.success = {m: round(sum(r.success for r in v) / len(v), 4) for m, v in per.items()}
        summary.trials = {m: len(v) for m, v in per.items()}
        summary.verifier_errors = {m: sum(r.verifier_errors for r in v) for m, v in per.items()}
        summary.verifier_unavailable = {m: sum(r.verifier_unavailable for r in v) for m, v in per.items()}
        audited = {m: sum(r.subplans_audited for r in v) for m, v in per.items()}
        summary.alignment = {m: (round(sum(r.subplans_aligned for r in v) / audited[m], 4) if audited[m] else None)
                             for m, v in per.items()}
    return summary
