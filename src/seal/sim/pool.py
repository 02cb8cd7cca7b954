"""EnvPool: K copies of one LIBERO world, stepped in parallel by worker processes.

Each worker process builds the task's world once and hosts several *slots* (one per
candidate). Because snapshot/restore is exact (bit-identical replays), a slot is just its
latest snapshot: to step slot j the worker restores j's snapshot, steps, and snapshots again.
That costs ~0.1 ms per switch and saves building K worlds (~8 s and ~150 MB each).

The parent keeps every slot's latest snapshot. If a worker dies, the pool notices (its pipe
closes / its process sentinel fires), starts a new worker, restores that worker's slots from
their latest snapshots, and reports a `WorkerCrashed` error for the affected slots of the
command that was running; other slots' results are unaffected.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import threading
import time
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait

import numpy as np

from seal.errors import InvalidInput, SimulationError, WorkerCrashed
from seal.sim.observation import Observation
from seal.sim.snapshot import Snapshot
from seal.sim.suites import TaskSpec, get_task


@dataclass
class SlotResult:
    """What happened to one slot in one pool command."""

    slot: int
    snapshot: Snapshot | None = None  # the slot's state after the command
    success: bool = False  # LIBERO's task success on that state
    steps: int = 0  # executed steps of this chunk (it may stop early on success)
    sim_error: bool = False  # physics went unstable: the candidate is void
    error: str | None = None  # worker crash or other failure, with the reason
    observation: Observation | None = None
    physics_s: float = 0.0  # worker time in physics for this command (runtime breakdown)
    render_s: float = 0.0  # worker time drawing camera images for the observation

    @property
    def ok(self) -> bool:
        return self.error is None and not self.sim_error


# ---- worker side ----------------------------------------------------------------------------
def ignore_interrupts() -> None:
    """For a worker process: Ctrl-C reaches every process of the terminal's group, and the parent
    handles it (it closes its workers); a worker stopped mid-step would only print a traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _worker_main(conn: Connection, task: TaskSpec, render_mode: str, physics=None, fast_step: bool = True) -> None:
    ignore_interrupts()
    from seal.sim.world import LiberoWorld

    world = LiberoWorld(task, render_mode=render_mode, physics=physics, fast_step=fast_step)
    slots: dict[int, Snapshot] = {}
    conn.send(("ready", os.getpid()))
    while True:
        try:
            cmd, payload = conn.recv()
        except (EOFError, KeyboardInterrupt):
            break
        if cmd == "close":
            break
        try:
            conn.send(("ok", _HANDLERS[cmd](world, slots, payload)))
        except Exception as exc:  # report, keep serving
            conn.send(("err", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))
    world.close()


def _h_set(world, slots, payload):
    snap, ids = payload
    world.restore(snap)  # validates the task before any slot takes it
    for i in ids:
        slots[i] = snap
    return None


def _h_reset(world, slots, payload):
    init_index, ids = payload
    world.reset(init_index)
    snap = world.snapshot()
    for i in ids:
        slots[i] = snap
    return snap


def _h_step(world, slots, payload):
    chunks, stop_on_success, observe = payload[:3]
    images, atoms = payload[3] if len(payload) > 3 else (True, None)
    out = []
    for i, actions in chunks.items():
        world.restore(slots[i])
        start = world.steps
        res = SlotResult(slot=i)
        t0 = time.perf_counter()
        try:
            res.success = world.step_chunk(actions, stop_on_success=stop_on_success).success
        except SimulationError as exc:
            res.sim_error, res.error = True, str(exc)
        res.physics_s = time.perf_counter() - t0
        res.steps = world.steps - start
        if not res.sim_error:
            slots[i] = res.snapshot = world.snapshot()
            if observe:
                drawn = world.render_seconds
                res.observation = world.observe(images=images, privileged_atoms=atoms)
                res.render_s = world.render_seconds - drawn
        out.append(res)
    return out


def _h_observe(world, slots, payload):
    ids, images, atoms = payload
    out = []
    for i in ids:
        world.restore(slots[i])
        out.append(world.observe(images=images, privileged_atoms=atoms))
    return out


def _h_check(world, slots, payload):
    ids, atoms = payload
    out = []
    for i in ids:
        world.restore(slots[i])
        out.append({str(a): world.check(a) for a in atoms})
    return out


def _h_render(world, slots, payload):
    ids, cameras, size = payload
    out = []
    for i in ids:
        world.restore(slots[i])
        out.append(world.render_raw(cameras, size))
    return out


def _h_prepare(world, slots, payload):
    for size in payload:  # builds the render model (fast mode: decimated meshes) and a renderer
        world.render_raw(("agentview",), size)
    return None


def _h_crash(world, slots, payload):  # test hook: die like a segfault would
    os._exit(1)


_HANDLERS = {
    "set": _h_set,
    "reset": _h_reset,
    "step": _h_step,
    "observe": _h_observe,
    "check": _h_check,
    "render": _h_render,
    "prepare": _h_prepare,
    "crash": _h_crash,
}


# ---- parent side ----------------------------------------------------------------------------
WAIT_SLICE_S = 5.0


def wait_awake(objects: list, timeout: float, *, waiter=wait, clock=time.monotonic) -> list:
    """`multiprocessing.connection.wait`, with ``timeout`` counted in time this process was awake.
    A run paused with Ctrl-Z or SIGSTOP has its workers paused too; counted in wall time, the pause
    would spend their whole timeout and the first wait after resuming would give up on a worker that
    is about to answer. Waiting in slices and counting a slice as at most its own length leaves the
    pause out."""
    waited = 0.0
    while True:
        step = min(WAIT_SLICE_S, timeout - waited)
        start = clock()
        ready = waiter(objects, max(step, 0.0))
        if ready:
            return ready
        waited += min(clock() - start, step)  # a slice far longer than asked was a pause
        if waited >= timeout:
            return []


class _Worker:
    def __init__(self, ctx, task: TaskSpec, render_mode: str, physics=None, fast_step: bool = True):
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_worker_main, args=(child, task, render_mode, physics, fast_step),
                                   daemon=True)
        # Started with SIGINT ignored (inherited by the new interpreter, which keeps ignoring it), so a
        # Ctrl-C while it imports cannot print a traceback either; the parent's own handler is restored.
        main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
        try:
            self.process.start()
        finally:
            if main and previous is not None:
                signal.signal(signal.SIGINT, previous)
        child.close()

    def wait_ready(self, timeout: float) -> None:
        tag, _ = self.recv(timeout)
        assert tag == "ready"

    def recv(self, timeout: float):
        ready = wait_awake([self.conn, self.process.sentinel], timeout)
        if self.conn in ready:
            try:
                return self.conn.recv()
            except (EOFError, ConnectionResetError):
                pass
        elif not ready:
            raise TimeoutError(f"pool worker pid {self.process.pid} gave no answer within {timeout:.0f} s")
        raise WorkerCrashed(f"pool worker pid {self.process.pid} died (exit code {self.process.exitcode})")

    def kill(self) -> None:
        if self.process.is_alive():
            self.process.kill()
        self.process.join(5)
        self.conn.close()


class EnvPool:
    """K slots of one task's world over ``workers`` processes (default: min(K, cores))."""

    def __init__(self, task: TaskSpec | tuple[str, int], k: int, *, workers: int | None = None,
                 render_mode: str = "stock", timeout: float = 600.0, physics=None, fast_step: bool = True):
        if not isinstance(task, TaskSpec):
            task = get_task(*task)
        if k < 1:
            raise InvalidInput(f"pool size k must be >= 1, got {k}")
        cores = os.cpu_count() or 1
        workers = min(k, cores) if workers is None else workers
        if not 1 <= workers <= k:
            raise InvalidInput(f"workers must be in 1..{k} for k={k}, got {workers}")
        self.task, self.k, self.render_mode, self.timeout = task, k, render_mode, timeout
        self.physics = physics  # a PhysicsMismatch for every slot's world, or None
        self.fast_step = fast_step  # the worlds' control step (LiberoWorld.fast_step): same states either way
        self._ctx = mp.get_context("spawn")  # never fork a process holding GL/MuJoCo state
        self._owner = [i % workers for i in range(k)]  # slot -> worker index
        self._latest: list[Snapshot | None] = [None] * k
        self._workers = [_Worker(self._ctx, task, render_mode, physics, fast_step) for _ in range(workers)]
        for w in self._workers:
            w.wait_ready(timeout)
        self.crashes = 0

    @property
    def num_workers(self) -> int:
        return len(self._workers)

    def slots_of(self, worker: int) -> list[int]:
        return [s for s, w in enumerate(self._owner) if w == worker]

    def worker_pids(self) -> list[int]:
        return [w.process.pid for w in self._workers]

    # ---- commands -----------------------------------------------------------------------
    def reset(self, init_index: int) -> Snapshot:
        """Every slot to official init state ``init_index`` (after the settle steps)."""
        results = self._broadcast(lambda wi: ("reset", (init_index, self.slots_of(wi))))
        snap = next(iter(results.values()))
        self._latest = [snap] * self.k
        return snap

    def sync(self, snap: Snapshot) -> None:
        """Every slot to one snapshot (the commit step of steering)."""
        self._broadcast(lambda wi: ("set", (snap, self.slots_of(wi))))
        self._latest = [snap] * self.k

    def step(self, chunks: dict[int, np.ndarray] | list[np.ndarray | None], *, stop_on_success: bool = False,
             observe: bool = False, images: bool = True, privileged_atoms=None) -> list[SlotResult]:
        """Step slots with their own action chunks, in parallel across workers.

        ``chunks`` maps slot -> (n, 7) actions (a list means slot = position; None skips a slot).
        With ``observe`` each result carries the observation after the chunk (``images`` and
        ``privileged_atoms`` as in `LiberoWorld.observe`), saving a round trip.
        Returns one `SlotResult` per stepped slot, in slot order.
        """
        if isinstance(chunks, (list, tuple)):
            chunks = {i: c for i, c in enumerate(chunks) if c is not None}
        for slot, c in chunks.items():
            self._check_slot(slot)
            c = np.asarray(c)
            if c.ndim != 2 or c.shape[1] != 7:
                raise InvalidInput(f"chunk for slot {slot} must have shape (n, 7), got {c.shape}")
        per_worker: dict[int, dict] = {}
        for slot, c in chunks.items():
            per_worker.setdefault(self._owner[slot], {})[slot] = np.asarray(c, dtype=np.float64)
        obs_opts = (images, None if privileged_atoms is None else list(privileged_atoms))
        answers = self._scatter({wi: ("step", (ch, stop_on_success, observe, obs_opts))
                                 for wi, ch in per_worker.items()})
        results: list[SlotResult] = []
        for wi, ch in per_worker.items():
            answer = answers[wi]
            if isinstance(answer, BaseException):
                results += [SlotResult(slot=s, error=str(answer)) for s in ch]
                continue
            for res in answer:
                if res.snapshot is not None:
                    self._latest[res.slot] = res.snapshot
                results.append(res)
        return sorted(results, key=lambda r: r.slot)

    def observe(self, slots=None, *, images: bool = True, privileged_atoms=None) -> list[Observation]:
        atoms = None if privileged_atoms is None else list(privileged_atoms)
        return self._gather("observe", slots, lambda ids: (ids, images, atoms))

    def check(self, atoms, slots=None) -> list[dict[str, bool]]:
        return self._gather("check", slots, lambda ids: (ids, list(atoms)))

    def render(self, cameras=("agentview",), slots=None, size: int = 256) -> list[dict[str, np.ndarray]]:
        return self._gather("render", slots, lambda ids: (ids, tuple(cameras), size))

    def prepare_render(self, sizes=(256,)) -> None:
        """Build every worker's render model and renderers for these sizes now, so the first
        observation with images does not pay for it (benchmarks time steps, not set-up)."""
        self._broadcast(lambda wi: ("prepare", tuple(int(s) for s in sizes)))

    def snapshot(self, slot: int) -> Snapshot:
        self._check_slot(slot)
        return self._latest[slot]

    def close(self) -> None:
        for w in self._workers:
            try:
                w.conn.send(("close", None))
            except (BrokenPipeError, OSError):
                pass
        for w in self._workers:
            w.process.join(10)
            w.kill()
        self._workers = []

    def __enter__(self) -> "EnvPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- plumbing -----------------------------------------------------------------------
    def _check_slot(self, slot: int) -> None:
        if not 0 <= slot < self.k:
            raise InvalidInput(f"slot {slot} out of range; valid: 0..{self.k - 1}")

    def _gather(self, cmd: str, slots, make_payload) -> list:
        slots = list(range(self.k)) if slots is None else list(slots)
        for s in slots:
            self._check_slot(s)
        per_worker: dict[int, list[int]] = {}
        for s in slots:
            per_worker.setdefault(self._owner[s], []).append(s)
        answers = self._scatter({wi: (cmd, make_payload(ids)) for wi, ids in per_worker.items()})
        by_slot = {}
        for wi, ids in per_worker.items():
            if isinstance(answers[wi], BaseException):
                raise answers[wi]
            by_slot.update(zip(ids, answers[wi]))
        return [by_slot[s] for s in slots]

    def _broadcast(self, make_msg) -> dict:
        answers = self._scatter({wi: make_msg(wi) for wi in range(self.num_workers)})
        for a in answers.values():
            if isinstance(a, BaseException):
                raise a
        return answers

    def _scatter(self, msgs: dict[int, tuple]) -> dict:
        """Send each worker its message, then collect; a dead worker's answer is a WorkerCrashed."""
        sent = {}
        for wi, msg in msgs.items():
            try:
                self._workers[wi].conn.send(msg)
                sent[wi] = True
            except (BrokenPipeError, OSError):
                sent[wi] = False
        answers = {}
        for wi in msgs:
            try:
                if not sent[wi]:
                    raise WorkerCrashed(f"pool worker pid {self._workers[wi].process.pid} is gone")
                tag, value = self._workers[wi].recv(self.timeout)
                answers[wi] = value if tag == "ok" else _remote_error(value)
            except WorkerCrashed as exc:
                answers[wi] = exc
                self._respawn(wi)
        return answers

    def _respawn(self, wi: int) -> None:
        self.crashes += 1
        self._workers[wi].kill()
        worker = _Worker(self._ctx, self.task, self.render_mode, self.physics, self.fast_step)
        worker.wait_ready(self.timeout)
        self._workers[wi] = worker
        # Put each of its slots back where it was last seen.
        for slot in self.slots_of(wi):
            snap = self._latest[slot]
            if snap is not None:
                worker.conn.send(("set", (snap, [slot])))
                tag, value = worker.recv(self.timeout)
                if tag != "ok":
                    raise _remote_error(value)


def _remote_error(text: str) -> Exception:
    head = text.splitlines()[0]
    if head.startswith("InvalidInput"):
        return InvalidInput(head.split(": ", 1)[1])
    return RuntimeError(f"pool worker failed: {text}")
