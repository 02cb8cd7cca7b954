"""Where trials run: local worker processes (default) or Ray actors on a cluster.

Both backends take an ordered list of `TrialSpec` and yield `TrialRow`s as trials finish; the
caller (one process) writes them to the results store, so the store never has two writers.
Each worker (process or actor) owns one `TrialRunner`, i.e. one env pool reused across the
trials of a task. Each worker has exactly one trial in flight, so when a worker dies the
backend knows which trial to record as an error.
"""

from __future__ import annotations

import multiprocessing as mp
import traceback
from multiprocessing.connection import wait
from typing import Iterator, Protocol, Sequence

from seal.errors import InvalidInput
from seal.eval.execute import RunOptions, TrialRunner
from seal.eval.store import TrialRow
from seal.eval.trials import TrialSpec

BACKENDS = ("local", "ray")


class Backend(Protocol):
    def run(self, trials: Sequence[TrialSpec]) -> Iterator[TrialRow]:
        """Yield one row per trial, in completion order."""
        ...

    def close(self) -> None: ...


def crashed_row(spec: TrialSpec, why: str, worker: str = "") -> TrialRow:
    import time

    return TrialRow(method=spec.method.label, config_hash=spec.method.config_hash, suite=spec.suite,
                    task=spec.task, trial=spec.trial, init_index=spec.init_index, seed=spec.seed,
                    status="error", error=why, worker=worker, finished_at=time.time())


# ---- local processes ----------------------------------------------------------------------
def _exit_with_parent(parent: int) -> None:
    """Die as soon as the coordinating process is gone (even SIGKILLed): an orphaned worker
    would finish its trial and write into a trial directory that a resumed run rewrites."""
    import os
    import time

    while os.getppid() == parent:
        time.sleep(0.5)
    os._exit(1)


def _local_worker(conn, options: RunOptions, name: str) -> None:
    import os
    import signal
    import threading

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us
    threading.Thread(target=_exit_with_parent, args=(os.getppid(),), daemon=True).start()
    runner = TrialRunner(options, worker_name=f"{name}:{os.getpid()}")
    try:
        while True:
            spec = conn.recv()
            if spec is None:
                break
            conn.send(runner.run(spec))
    except (EOFError, BrokenPipeError):
        pass
    finally:
        runner.close()


class LocalBackend:
    """``workers`` spawned processes on this machine."""

    def __init__(self, options: RunOptions, workers: int = 1):
        if workers < 1:
            raise InvalidInput(f"--workers must be >= 1, got {workers}")
        self.options, self.n = options, workers
        self._ctx = mp.get_context("spawn")  # never fork a process that may hold GL state
        self._procs: list = []
        self._spawned = 0

    def _spawn(self):
        self._spawned += 1
        parent, child = self._ctx.Pipe()
        name = f"local-{self._spawned}"
        proc = self._ctx.Process(target=_local_worker, args=(child, self.options, name), name=name)
        proc.start()
        child.close()
        return [proc, parent, None, name]  # process, pipe, trial in flight, name

    def run(self, trials: Sequence[TrialSpec]) -> Iterator[TrialRow]:
        todo = list(trials)[::-1]  # pop() from the end keeps the given order
        self._procs = [self._spawn() for _ in range(min(self.n, len(todo)))]
        try:
            for w in self._procs:
                self._feed(w, todo)
            while any(w[2] is not None for w in self._procs):
                busy = [w for w in self._procs if w[2] is not None]
                ready = wait([w[1] for w in busy] + [w[0].sentinel for w in busy])
                for i, w in enumerate(self._procs):
                    if w[2] is None or not (w[1] in ready or w[0].sentinel in ready):
                        continue
                    row = self._receive(w)
                    if row is None:  # the worker died with the trial in flight
                        row = crashed_row(w[2], f"worker {w[3]} died (exit code {w[0].exitcode})", w[3])
                        w[1].close()
                        w = self._procs[i] = self._spawn()
                    else:
                        w[2] = None
                    yield row
                    self._feed(w, todo)
        finally:
            self.close()

    @staticmethod
    def _receive(w):
        try:
            if w[1].poll():
                return w[1].recv()
        except (EOFError, ConnectionResetError, OSError):
            pass
        return None

    @staticmethod
    def _feed(w, todo: list) -> None:
        w[2] = todo.pop() if todo else None
        if w[2] is not None:
            w[1].send(w[2])

    def close(self) -> None:
        for proc, conn, *_ in self._procs:
            try:
                conn.send(None)
            except (BrokenPipeError, OSError):
                pass
        for proc, conn, *_ in self._procs:
            proc.join(5)
            if proc.is_alive():
                proc.kill()
                proc.join(5)
            conn.close()
        self._procs = []


# ---- Ray ----------------------------------------------------------------------------------
class RayBackend:
    """``workers`` Ray actors (one CPU each), on a running cluster (``address``) or a local one."""

    def __init__(self, options: RunOptions, workers: int = 1, address: str | None = None):
        try:
            import ray
        except ImportError:
            raise InvalidInput("the ray backend needs the `ray` package: pip install 'seal[ray]'") from None
        if workers < 1:
            raise InvalidInput(f"--workers must be >= 1, got {workers}")
        self.ray, self.options, self.n = ray, options, workers
        self._owns_cluster = not ray.is_initialized()
        if self._owns_cluster:
            # Workers import seal from the same installed package; no runtime_env upload needed.
            ray.init(address=address, include_dashboard=False, log_to_driver=False,
                     **({} if address else {"num_cpus": max(workers, 1)}))
        self._actor_cls = ray.remote(num_cpus=1, max_restarts=0)(_RayTrialActor)
        self._actors: list = []

    def run(self, trials: Sequence[TrialSpec]) -> Iterator[TrialRow]:
        ray = self.ray
        todo = list(trials)[::-1]
        self._actors = [self._actor_cls.remote(self.options, f"ray-{i}") for i in range(min(self.n, len(todo)))]
        inflight: dict = {}  # object ref -> (actor index, spec)

        def feed(i: int) -> None:
            if todo:
                spec = todo.pop()
                inflight[self._actors[i].run.remote(spec)] = (i, spec)

        for i in range(len(self._actors)):
            feed(i)
        try:
            while inflight:
                done, _ = ray.wait(list(inflight), num_returns=1)
                ref = done[0]
                i, spec = inflight.pop(ref)
                try:
                    row = ray.get(ref)
                except ray.exceptions.RayActorError as exc:  # the actor's process died
                    row = crashed_row(spec, f"ray actor ray-{i} died: {exc}", f"ray-{i}")
                    self._actors[i] = self._actor_cls.remote(self.options, f"ray-{i}")
                except ray.exceptions.RayError:
                    row = crashed_row(spec, traceback.format_exc(), f"ray-{i}")
                yield row
                feed(i)
        finally:
            for ref in inflight:
                ray.cancel(ref, force=True)
            self.close()

    def close(self) -> None:
        for actor in self._actors:
            try:
                self.ray.get(actor.close.remote(), timeout=30)
            except Exception:  # a dead actor has nothing to close
                pass
            self.ray.kill(actor)
        self._actors = []

    def shutdown(self) -> None:
        if self._owns_cluster and self.ray.is_initialized():
            self.ray.shutdown()


class _RayTrialActor:
    def __init__(self, options: RunOptions, name: str):
        self.runner = TrialRunner(options, worker_name=name)

    def run(self, spec: TrialSpec) -> TrialRow:
        return self.runner.run(spec)

    def close(self) -> None:
        self.runner.close()


def make_backend(name: str, options: RunOptions, workers: int, address: str | None = None):
    if name == "local":
        return LocalBackend(options, workers)
    if name == "ray":
        return RayBackend(options, workers, address)
    raise InvalidInput(f"unknown backend {name!r}; valid: {', '.join(BACKENDS)}")
