"""`seal demos dagger`: the learned VLA acts, the scripted expert labels the states it reaches.

DAgger (Ross et al., 2011) with the scripted expert as the teacher. An episode starts from a
freshly sampled start (never an official init state; its own seed namespace per round, apart from
the recordings' and the held-out rollouts'); at every chunk boundary (every 5 steps) the state is
recorded, as the VLA sees it (both cameras at its size, in its render model, and the 8-d state),
together with what the expert says about *that exact state*:

- the reasoning it would write there (plans, done, now: `ScriptedExpert.reason`),
- the 16-step action chunk it would act with (`ScriptedExpert.act` on that reasoning),
- whether the VLA should think now: the sub-plan the VLA is acting on is not the one the expert
  says is next (done already, skipped, or garbled text), and the VLA's own reasoning text (the
  stale text a think sample is conditioned on).

Then a chunk is executed: the VLA's own (re-reasoning first when its think head fires), or with
probability ``beta`` the expert's (the DAgger mixture; beta = 1 is plain expert recording).

Where the teacher has no answer (a motion primitive that cannot plan from this state, a skill that
says "done" while its sub-goal does not hold, a non-finite chunk), the frame is kept with
``valid = False`` and the reason; training never uses its action or text label (`seal train vla`).

Output: ``OUT/dataset`` is a LeRobot v2.1 dataset with one frame per chunk boundary (``action`` is the
first step of the expert's chunk); ``OUT/annotations`` is an annotation sidecar in `seal annotate`'s
layout whose per-episode label files carry, per frame, the expert's reasoning text, the VLA's,
the think label, the validity, the whole expert chunk and the actions the world then executed
(``executed``: the VLA's or the expert's, up to the next boundary; empty where the episode ended
on the VLA's word). `seal train vla --annotations
DEMOS_ANN,OUT/annotations --mix ...` trains on both. Resumable like `seal demos record`: every
attempt is logged, and the same command continues where it stopped.

The non-reasoning twin (the pi0 baseline) can be rolled out too: its own states with the expert's
action labels (DAgger for the twin), and its executed chunks for offline RL (`seal train value
--rollouts`); its reasoning columns hold the expert's text, its own is the instruction, and it never
thinks.

With ``verifier_cases`` (``--verifier-cases DIR``) the same rollouts also yield verification cases
(`seal.verify.dataset` layout) from the VLA's own states, labelled by the oracle: see
`VerifierCaseTaker`. Off by default; on or off, the rollout and what the DAgger dataset records are
the same (the cases only read the world, render 224-px views on a renderer of their own, and take no
random draw).
"""

from __future__ import annotations

import json
import multiprocessing
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seal.datasets import Episode, LeRobotWriter
from seal.datasets.lerobot import read_jsonl
from seal.errors import InvalidInput, SealError
from seal.policies.base import ACTION_HORIZON, PREDICT_HORIZON, Reasoning
from seal.sim.fast_assets import CACHE_VERSION as FAST_VERSION
from seal.sim.goals import GRASP_CHECKS
from seal.sim.suites import get_task, task_count

ATTEMPTS = "attempts.jsonl"
DATASET_DIR = "dataset"
ANNOTATIONS_DIR = "annotations"
BACKEND = "dagger"
# where `run_dagger_episode` hands a rollout's verification cases to the collector: a key of the attempt
# dict, popped before the attempt is logged (callers that unpack four values, `seal bench vla`, stay as
# they are, and no image bytes reach attempts.jsonl)
CASES_KEY = "_verifier_cases"
CASES_SOURCE = "fresh-train"  # DAgger starts are fresh sampled starts of a namespace of their own


def dagger_seed(task_key: str, round_: int, episode: int) -> int:
    """First seed tried for a DAgger start: its own namespace per round, so no round shares a start
    with another, with the recordings (`seal.demos.start_seed`) or with held-out rollouts."""
    from seal.demos import start_seed

    return start_seed(task_key, episode, namespace=f"dagger{round_}")


@dataclass(frozen=True)
class DaggerJob:
    suite: str
    task_id: int
    episode: int
    round: int
    ckpt: str
    beta: float
    render_mode: str
    image_size: int
    max_steps: int | None = None
    start_seed: int | None = None  # None: this round's own start (`dagger_seed`); held-out checks pass theirs
    teacher_check: bool = False  # also let the expert finish alone from one boundary (`teacher_recovers`)
    verifier_cases: bool = False  # also take verification cases from the VLA's states (`VerifierCaseTaker`)
    closed_loop: bool = True  # chunk labels: the expert's executed actions from each state (`teacher_label`)
    noise_scale: float = 1.0  # the VLA's flow noise scale (`VLAPolicy.noise_scale`; held-out checks may set it)


@dataclass
class TeacherLabel:
    reasoning: Reasoning
    chunk: np.ndarray  # (PREDICT_HORIZON, 7)
    valid: bool
    why: str = ""  # why the teacher has no answer (valid False)
    steps: int = PREDICT_HORIZON  # how many of the chunk's actions are the teacher's (the rest: the episode ended)


def teacher_label(expert, obs, world=None) -> TeacherLabel:
    """What the scripted expert would write and do in ``obs``'s state (it reads only the scene).

    With ``world`` (in ``obs``'s state) the chunk is *closed-loop*: what the expert does over the
    next PREDICT_HORIZON steps when it runs from here, re-planning every ACTION_HORIZON steps and
    moving to its next sub-plan when one is done, exactly as in a recorded demonstration (whose
    training chunks are windows of its executed actions). The world is restored afterwards.
    Without it, the expert's own one-shot extrapolation: its first ACTION_HORIZON steps are what it
    executes, its tail is not (on replayed demonstrations the tail differs from the executed
    actions by about half their variance, `docs/dagger.md`).
    """
    reasoning = expert.reason(obs)
    empty = np.zeros((PREDICT_HORIZON, 7), np.float32)
    if reasoning.finished:
        return TeacherLabel(reasoning, empty, False, "the task's goal holds: nothing left to do")
    expert.begin(1)
    try:
        chunk = expert.act([obs], reasoning)[0]
    except SealError as exc:  # a motion primitive that cannot plan from here
        return TeacherLabel(reasoning, empty, False, f"no plan: {exc}")
    if chunk.think:
        return TeacherLabel(reasoning, empty, False, f"the skill for {reasoning.now!r} says done, its sub-goal does not hold")
    actions = np.asarray(chunk.actions, np.float32)
    steps = PREDICT_HORIZON
    if world is not None:  # its first chunk is the one above: the expert plans the same way twice
        actions, steps = _closed_loop(world, expert, reasoning, obs, actions)
        expert.reason(obs)  # the expert's own state back where the label was asked
    if not np.isfinite(actions).all():
        return TeacherLabel(reasoning, empty, False, "non-finite chunk")
    return TeacherLabel(reasoning, actions, True, steps=steps)


def expert_steps(world, expert, obs, reasoning: Reasoning, atoms):
    """The expert acting from the world's state as in a demonstration: each chunk's first
    ACTION_HORIZON actions, then a fresh plan; on to its next sub-plan when one is done. Yields
    (index within the chunk, action) *before* the world takes that step, so a caller can snapshot a
    boundary or stop; it ends when the goal holds, the plan is finished, or a skill says "done"
    right after a re-plan (the teacher has no move there). A `SealError` of a primitive propagates.
    """
    expert.begin(1)
    fresh = False  # the reasoning was just re-read: a second "done" means there is no move
    while not world.success() and not reasoning.finished:
        chunk = expert.act([obs], reasoning)[0]
        if chunk.think:
            if fresh:
                return
            reasoning, fresh = expert.reason(obs), True
            expert.begin(1)
            continue
        fresh = False
        for i, action in enumerate(chunk.actions[:ACTION_HORIZON]):
            yield i, np.asarray(action, np.float32)
            world.step(action)
            obs = world.observe(images=False, privileged_atoms=atoms)
            if world.success():
                return


def _closed_loop(world, expert, reasoning: Reasoning, obs, one_shot: np.ndarray) -> tuple[np.ndarray, int]:
    """The expert's next PREDICT_HORIZON executed actions from the world's state (restored after);
    (actions padded with the last one, how many are real). Should the expert not act at all on the
    second asking, the one-shot chunk's executed prefix stands in."""
    snap = world.snapshot()
    taken: list[np.ndarray] = []
    try:
        for _, action in expert_steps(world, expert, obs, reasoning, expert.privileged_atoms()):
            taken.append(action)
            if len(taken) == PREDICT_HORIZON:
                break
    except SealError:
        pass  # the teacher has no plan from there: the label is what it did up to that point
    finally:
        world.restore(snap)
    if not taken:
        return one_shot, ACTION_HORIZON
    out = np.empty((PREDICT_HORIZON, 7), np.float32)
    out[:len(taken)] = taken
    out[len(taken):] = taken[-1]
    return out, len(taken)


@dataclass
class DaggerFrames:
    agent: list = field(default_factory=list)
    wrist: list = field(default_factory=list)
    states: list = field(default_factory=list)
    rows: list = field(default_factory=list)  # per frame: labels (see `label_columns`)


# One world and one policy per process, rebuilt only when the task or checkpoint changes.
_CACHE: dict = {}


def _world_and_policy(job: DaggerJob):
    from seal.policies.vla.policy import VLAPolicy
    from seal.sim.world import LiberoWorld

    key = (job.suite, job.task_id, job.render_mode)
    if _CACHE.get("world_key") != key:
        if "world" in _CACHE:
            _CACHE.pop("world").close()
        _CACHE["world"] = LiberoWorld(get_task(job.suite, job.task_id), render_mode=job.render_mode)
        _CACHE["world_key"] = key
    if _CACHE.get("ckpt") != job.ckpt:
        _CACHE["policy"] = VLAPolicy.load(job.ckpt)
        _CACHE["ckpt"] = job.ckpt
    _CACHE["policy"].noise_scale = float(job.noise_scale)  # per job: the cached policy serves every job
    return _CACHE["world"], _CACHE["policy"]


def run_dagger_episode(job: DaggerJob) -> tuple[DaggerJob, dict, Episode | None, list[dict]]:
    """One rollout of the VLA (mixed with the expert at rate ``beta``), labelled at every chunk boundary."""
    from seal.policies.expert.policy import ScriptedExpert

    world, vla = _world_and_policy(job)
    expert = ScriptedExpert.for_world(world)
    first = job.start_seed if job.start_seed is not None else dagger_seed(world.task.key, job.round, job.episode)
    seed = world.reset_sampled(first)
    vla.reset(world.instruction, seed)
    expert.reset(world.instruction, seed)
    mix = np.random.default_rng([seed, job.round, 0xDA66])
    atoms = expert.privileged_atoms()
    max_steps = job.max_steps or world.task.max_steps
    rec = DaggerFrames()
    obs = world.observe(images=job.image_size, privileged_atoms=atoms)
    mine = vla.reason(obs)
    vla.begin(1)
    taker = VerifierCaseTaker(world, job, seed) if job.verifier_cases else None
    if taker is not None:
        taker.begin(mine)
    grip_closed = False  # the gripper command in force (the last executed action's): the reset leaves it open
    ended, executed = "steps", {"vla": 0, "expert": 0}
    sim_error = False
    # the boundary the teacher check starts from: the first at or after a step drawn in advance
    check_at = int(np.random.default_rng([seed, job.round, 0x7EAC]).integers(0, max_steps)) if job.teacher_check else None
    check = None
    try:
        while not world.success() and world.steps < max_steps:
            if check_at is not None and check is None and world.steps >= check_at:
                check = (world.snapshot(), world.steps, len(rec.rows))
            label = teacher_label(expert, obs, world if job.closed_loop else None)
            # think: the sub-plan the VLA acts on is not the next one (done already, skipped or garbled); a
            # non-reasoning twin acts on the instruction and never thinks
            think = vla.cfg.reasoning and mine.now != label.reasoning.now
            rec.agent.append(obs.agent)
            rec.wrist.append(obs.wrist)
            rec.states.append(obs.state.astype(np.float32))
            rec.rows.append({"reasoning": label.reasoning.text(), "now": label.reasoning.now,
                             "vla_reasoning": mine.text(), "vla_now": mine.now, "think": bool(think),
                             "valid": label.valid, "why": label.why, "chunk": label.chunk.reshape(-1),
                             "chunk_steps": label.steps if job.closed_loop else ACTION_HORIZON,
                             "step": world.steps,
                             # what the world then took from this state (the VLA's or the expert's actions, up
                             # to the next boundary or the episode's end): the transitions offline RL learns from
                             "executed": []})
            if taker is not None:
                taker.boundary(grip_closed)
            if mine.finished:  # the VLA declared the task done while it is not: a label, and the end
                ended = "vla_done"
                if taker is not None:
                    taker.declared_done(mine)
                break
            if label.valid and mix.random() < job.beta:
                actions = label.chunk[:ACTION_HORIZON]
                executed["expert"] += 1
            else:
                chunk = vla.act([obs], mine)[0]
                if chunk.think:
                    if taker is not None:  # the VLA believes its sub-plan done: where SEAL asks the verifier
                        taker.end_subplan(grip_closed)
                    mine = vla.reason(obs)
                    vla.begin(1)
                    if taker is not None:
                        taker.begin(mine)
                    if mine.finished:
                        continue  # recorded at the next boundary (same state) with its new text
                    chunk = vla.act([obs], mine)[0]
                actions = chunk.actions[:ACTION_HORIZON]
                executed["vla"] += 1
            for i, action in enumerate(actions):
                world.step(action)
                rec.rows[-1]["executed"].append(np.asarray(action, np.float32))
                grip_closed = float(action[-1]) > 0  # LIBERO's gripper command: -1 open, +1 close
                last = i == len(actions) - 1
                obs = world.observe(images=job.image_size if last else False, privileged_atoms=atoms)
                if world.success() or world.steps >= max_steps:
                    break  # the episode ends here: no boundary after it to record
    except SealError as exc:
        sim_error, ended = True, f"error: {exc}"
    success = bool(world.success()) and not sim_error
    if success:
        ended = "success"
        if taker is not None:  # before anything below moves the world (the teacher check restores a snapshot)
            taker.solved()
    held = [] if sim_error else list(world.goal_status().values())
    attempt = {"suite": job.suite, "task_id": job.task_id, "init_index": job.episode, "round": job.round,
               "start_seed": seed, "success": success, "steps": world.steps, "ended": ended, "frames": len(rec.rows),
               "invalid_labels": sum(not r["valid"] for r in rec.rows), "executed": executed,
               "subgoals": round(sum(held) / len(held), 3) if held else 0.0}
    if not rec.rows:
        return job, attempt, None, []
    final_done = () if sim_error else expert.reason(obs).done  # what holds where the episode stopped
    attempt |= on_policy_figures(rec.rows, final_done)
    if check is not None:
        # a whole task's budget from there: is the state recoverable at all, not "in what the episode had left"
        attempt["teacher_check"] = teacher_recovers(world, check[0], max_steps) | {"from_step": check[1],
                                                                                  "frame": check[2]}
    plans = list(expert.plans(obs.scene)) if obs.scene is not None else []
    episode = Episode(
        instruction=world.instruction, agent_images=np.stack(rec.agent), wrist_images=np.stack(rec.wrist),
        states=np.stack(rec.states), actions=np.stack([r["chunk"][:7] for r in rec.rows]).astype(np.float32),
        subplans=[p.text for p in plans], critical_frames=[-1] * len(plans),
        meta={"suite": job.suite, "task_id": job.task_id, "init_index": job.episode, "start": "sampled",
              "start_seed": seed, "render_mode": job.render_mode, "image_size": job.image_size,
              # the rollout's own length (the teacher check above has moved the world since)
              "fast_version": FAST_VERSION if job.render_mode == "fast" else None, "steps": attempt["steps"],
              # the frames are chunk boundaries of the VLA's rollout; every label is the expert's at that state
              "success": success, "dagger": {"round": job.round, "beta": job.beta, "ckpt": job.ckpt,
                                             "ended": ended, "executed": executed,
                                             "frame_steps": [r["step"] for r in rec.rows]},
              "reasoning": [[r["step"], r["reasoning"]] for r in rec.rows]})
    if taker is not None:  # last: its held-versus-released cases restore earlier states of the world
        attempt[CASES_KEY] = taker.finish()
    return job, attempt, episode, rec.rows


@dataclass
class _Span:
    """One sub-plan the VLA acted on, from the boundary where it wrote it."""

    reasoning: Reasoning
    first_agent: np.ndarray  # 224-px agent view when it began
    number: int  # 1-based count of sub-plans begun in the episode
    start: int  # control step it began at
    held: object = None  # snapshot of its latest boundary with the gripper commanded closed
    held_step: int = -1


class VerifierCaseTaker:
    """Verification cases from one DAgger rollout: the VLA's own states, labelled by the oracle.

    The learned verifier had seen almost only expert-like states and calls many of the VLA's failures
    successes (issue 32). A DAgger rollout passes through exactly the states SEAL asks a verifier about
    when it steers this VLA, so each rollout also yields, in `seal.verify.dataset`'s layout:

    - ``think``: whenever the VLA's act says its sub-plan is done (the moment SEAL would ask the
      verifier): first view when that sub-plan began, final views now, the VLA's own ``now`` and plans;
    - ``vla_done``: when the VLA declares the task complete, a task-level case (the instruction, the
      task's goal atoms, the episode's first view as "before"); SEAL's done check asks this;
    - ``task_success``: the same task-level question where LIBERO's check first holds. A DAgger
      episode ends there, so every ``vla_done`` case is a failure; without these the task kind would
      have no positive at all;
    - ``before_release``: hard negatives on purpose. At a ``think`` case the oracle labels a successful
      place, the latest earlier boundary of that sub-plan at which the gripper was still commanded
      closed (if it was open at the end): the held-versus-released pair, with the wrist view showing
      the grip. Its state is restored from a snapshot after the rollout and rendered then, so the
      rollout renders 224-px views only at the moments above. Labelled by the oracle like the rest
      (an object held inside its target is in it; usually it is still above it).

    Every label is the oracle's on the privileged scene at that state; a sub-plan the oracle cannot
    ground (garbled text) gives no case and is counted as unknown. The taker only reads the world
    (snapshots, scene facts, renders on a renderer of its own: 256 px resized to openpi's 224) and
    draws nothing at random, so the rollout is the same with it and without it.
    """

    def __init__(self, world, job: DaggerJob, seed: int):
        from seal.verify.oracle import OracleVerifier

        t0 = time.perf_counter()
        self.world, self.job = world, job
        self.oracle = OracleVerifier()
        scene = world.scene_state()
        self.objects = sorted(set(scene.bodies) | set(scene.sites))
        self.base = {"suite": job.suite, "task_id": job.task_id, "task": world.task.key, "init_source": CASES_SOURCE,
                     "init_index": job.episode, "init_seed": int(seed), "episode": job.episode, "seed": int(seed),
                     "policy": "vla", "knobs": BACKEND, "instruction": world.instruction}
        self.rows: list[dict] = []
        self.unknown = 0
        self.errors = 0
        self.renders = 0
        self.span: _Span | None = None
        self.number = 0
        self.pending: list[tuple[_Span, dict]] = []  # held-versus-released cases, rendered after the rollout
        self._last: tuple[int, object] | None = None  # (step, 224-px observation): one render per state
        self.first = self._views()  # the episode's first agent view ("before" of task-level cases)
        self.seconds = time.perf_counter() - t0

    def _views(self):
        if self._last is None or self._last[0] != self.world.steps:
            self._last = (self.world.steps, self.world.observe(images=True))  # openpi's 224-px view, as SEAL's loop
            self.renders += 1
        return self._last[1]

    def _case(self, request, *, ended_by: str, number: int, steps: int) -> dict | None:
        """Label ``request`` at the world's current state and keep it (None: the oracle cannot tell)."""
        from seal.verify import dataset as ds

        views = self._views()
        request.final_agent, request.final_wrist = views.agent, views.wrist
        request.scene = self.world.scene_state(self.oracle.atoms_needed(request, self.objects))
        verdict = self.oracle.judge(request)
        if verdict.success is None:
            self.unknown += 1
            return None
        b = self.base
        case_id = f"{b['task']}:dagger{self.job.round}:{b['episode']}:s{number}:{ended_by}:{self.world.steps}"
        row = ds.case_row(b, request, verdict, case_id=case_id, subplan_number=number, round=0, candidate=0,
                          steps=steps, ended_by=ended_by)
        self.rows.append(row)
        return row

    def _request(self, span: _Span):
        from seal.verify.base import VerifyRequest

        r = span.reasoning
        return VerifyRequest(subplan=r.now, instruction=self.world.instruction, plans=tuple(r.plans), index=r.index,
                             first_agent=span.first_agent, task=self.world.task.key)

    def _task_request(self, plans):
        from seal.verify.base import VerifyRequest

        instruction = self.world.instruction
        return VerifyRequest(subplan=instruction, instruction=instruction, plans=tuple(plans),
                             first_agent=self.first.agent, task=self.world.task.key,
                             goal_atoms=tuple(str(a) for a in self.world.goal_atoms))

    def _guarded(self, fn, *args) -> None:
        # A case that cannot be taken (a scene fact the simulator refuses to check) is counted, never
        # allowed to end or alter the rollout it rides on.
        t0 = time.perf_counter()
        try:
            fn(*args)
        except SealError:
            self.errors += 1
        finally:
            self.seconds += time.perf_counter() - t0

    def begin(self, reasoning: Reasoning) -> None:
        """The VLA has written ``reasoning`` at this boundary: its sub-plan starts here."""
        def run():
            if reasoning.finished:
                self.span = None
                return
            first = self.first.agent if self.number == 0 else self._views().agent
            self.number += 1
            self.span = _Span(reasoning, first, self.number, self.world.steps)
        self._guarded(run)

    def boundary(self, closed: bool) -> None:
        """A chunk boundary; ``closed``: the gripper command in force here."""
        def run():
            if self.span is not None and closed:
                self.span.held, self.span.held_step = self.world.snapshot(), self.world.steps
        self._guarded(run)

    def end_subplan(self, closed: bool) -> None:
        """The VLA's act says its sub-plan is done (it will reason again)."""
        def run():
            span, self.span = self.span, None
            if span is None:
                return
            row = self._case(self._request(span), ended_by="think", number=span.number,
                             steps=self.world.steps - span.start)
            # a place the oracle says holds, released during the sub-plan: its last held state too
            if (row is not None and row["label"] and row["kind"] == "place" and not closed
                    and span.held is not None and span.held_step < self.world.steps):
                self.pending.append((span, row))
        self._guarded(run)

    def declared_done(self, reasoning: Reasoning) -> None:
        self._guarded(lambda: self._case(self._task_request(reasoning.plans), ended_by="vla_done",
                                         number=self.number, steps=self.world.steps))

    def solved(self) -> None:
        plans = self.span.reasoning.plans if self.span is not None else ()
        self._guarded(lambda: self._case(self._task_request(plans), ended_by="task_success", number=self.number,
                                         steps=self.world.steps))

    def finish(self) -> dict:
        """The held-versus-released cases (restoring the world to each held state), then everything."""
        def pair(span: _Span):
            self.world.restore(span.held)
            self._last = None
            self._case(self._request(span), ended_by="before_release", number=span.number,
                       steps=self.world.steps - span.start)
        for span, _ in self.pending:
            self._guarded(pair, span)
        return {"rows": self.rows, "unknown": self.unknown, "errors": self.errors, "renders": self.renders,
                "seconds": round(self.seconds, 3)}


def teacher_recovers(world, snap, budget: int) -> dict:
    """From a state the rollout reached, the clean expert alone until the goal holds or ``budget``
    more steps are spent: does the teacher have a good answer there, not only a label? (A dropped
    object, a drawer left half open, an object pushed out of reach: its labels then lead nowhere.)"""
    from seal.policies.expert.policy import ScriptedExpert

    world.restore(snap)
    expert = ScriptedExpert.for_world(world)
    atoms = expert.privileged_atoms()
    expert.reset(world.instruction, 0)
    obs = world.observe(images=False, privileged_atoms=atoms)
    reasoning = expert.reason(obs)
    end = world.steps + budget
    try:
        for _ in expert_steps(world, expert, obs, reasoning, atoms):
            if world.steps >= end:
                break
    except SealError as exc:
        return {"recovered": False, "steps": world.steps, "now": reasoning.now, "budget": budget, "error": str(exc)}
    return {"recovered": bool(world.success()), "steps": world.steps, "now": reasoning.now, "budget": budget}


def on_policy_figures(rows: list[dict], final_done=()) -> dict:
    """How the VLA's reasoning held up on its own states: ``subplan_accuracy`` (share of chunk
    boundaries where its sub-plan is the one the expert says is next) and ``alignment`` (share of
    the sub-plans it acted on, each span of one text, that were done when it moved on or stopped;
    ``final_done``: the sub-plans the expert counts as done where the episode ended)."""
    from seal.policies.base import parse_reasoning

    if not rows:
        return {"subplan_accuracy": None, "alignment": None, "committed": 0}
    accuracy = sum(r["vla_now"] == r["now"] for r in rows) / len(rows)
    spans, achieved = 0, 0
    for i, r in enumerate(rows):
        last = i + 1 == len(rows) or rows[i + 1]["vla_now"] != r["vla_now"]
        if last and r["vla_now"]:
            # done at the next boundary (after this span's last chunk), or where the episode stopped
            done = parse_reasoning(rows[i + 1]["reasoning"]).done if i + 1 < len(rows) else final_done
            spans += 1
            achieved += r["vla_now"] in done
    return {"subplan_accuracy": round(accuracy, 4), "alignment": round(achieved / spans, 4) if spans else None,
            "committed": spans}


def release_cached() -> None:
    """Close the world this process keeps between episodes and forget the loaded policy."""
    world = _CACHE.pop("world", None)
    if world is not None:
        world.close()
    _CACHE.clear()


@dataclass
class DaggerSummary:
    recorded: int = 0
    successes: int = 0
    skipped: int = 0
    frames: int = 0
    invalid_labels: int = 0
    think_labels: int = 0
    vla_done_early: int = 0
    teacher_checks: int = 0  # rollouts where the expert was let to finish alone from one boundary
    teacher_recovered: int = 0  # ...and reached the goal
    verifier_cases: int = 0  # with --verifier-cases: cases written by this run
    verifier_case_seconds: float = 0.0  # ...and the wall time spent taking them (renders, oracle, PNGs)


def _attempted(root: Path) -> set[tuple[str, int, int]]:
    """(suite, task, episode) of every attempt made, and of every episode whose labels were committed
    before a crash cut off its attempt line (a torn last line simply runs again)."""
    from seal.annotate.pipeline import ANNOTATIONS

    attempts, _ = read_jsonl(root / ATTEMPTS)
    labelled, _ = read_jsonl(root / ANNOTATIONS_DIR / ANNOTATIONS)
    return ({(a["suite"], a["task_id"], a["init_index"]) for a in attempts}
            | {tuple(r["start"]) for r in labelled if "start" in r})


def collect_dagger(suite: str, out: Path, *, ckpt: str, episodes_per_task: int, round_: int = 1, beta: float = 0.0,
                   tasks: list[int] | None = None, workers: int = 1, render_mode: str | None = None,
                   max_steps: int | None = None, teacher_check: bool = True, verifier_cases: Path | str | None = None,
                   progress=None) -> DaggerSummary:
    """Roll out ``ckpt`` on fresh starts and label every chunk boundary with the expert (resumable).
    ``verifier_cases``: a directory that also receives the rollouts' verification cases, one shard per
    recorded rollout (`VerifierCaseTaker`; docs/dagger.md)."""
    from seal.annotate.pipeline import ANNOTATIONS, INFO, LABELS_PATH, CHUNK_SIZE
    from seal.policies.vla.locate import checkpoint_digest, resolve_checkpoint, trained_render
    from seal.policies.vla.checkpoint import read_config

    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InvalidInput(f"--workers must be a positive integer, got {workers!r}")
    if isinstance(episodes_per_task, bool) or not isinstance(episodes_per_task, int) or not 1 <= episodes_per_task <= 999:
        raise InvalidInput(f"--episodes-per-task must be in 1..999, got {episodes_per_task!r}")
    if isinstance(round_, bool) or not isinstance(round_, int) or round_ < 1:
        raise InvalidInput(f"--round must be an integer >= 1, got {round_!r}")
    if not isinstance(beta, (int, float)) or isinstance(beta, bool) or not 0.0 <= beta <= 1.0:
        raise InvalidInput(f"--beta must be a probability in [0, 1] (the share of chunks the expert executes), got {beta!r}")
    if max_steps is not None and (not isinstance(max_steps, int) or max_steps < ACTION_HORIZON):
        raise InvalidInput(f"--max-steps must be >= {ACTION_HORIZON}, got {max_steps!r}")
    tasks = list(range(task_count(suite))) if tasks is None else tasks
    specs = [get_task(suite, t) for t in tasks]  # validates every id before any work
    where = resolve_checkpoint(ckpt)
    digest = checkpoint_digest(ckpt)  # refuses a damaged checkpoint before any output exists
    config = read_config(where)
    if not config.reasoning and verifier_cases is not None:
        raise InvalidInput(f"{where} is a non-reasoning twin: it writes no sub-plans, so its rollouts give no "
                           "verification cases (drop --verifier-cases, or roll out a reasoning VLA)")
    render = render_mode or trained_render(ckpt)["mode"]
    # teacher_grip: how the teacher tells an object is in the hand (`ScriptedExpert.grip`); collections from
    # before it existed read the pad check, so they refuse to resume with this teacher rather than mix labels
    settings = {"ckpt_digest": digest, "round": round_, "beta": float(beta), "render_mode": render,
                "image_size": config.image_size, "suite": suite, "max_steps": max_steps,
                "teacher_grip": GRASP_CHECKS[0]}
    out = Path(out)
    ann = out / ANNOTATIONS_DIR
    info_path = ann / INFO
    if info_path.is_file():
        saved = json.loads(info_path.read_text()).get("dagger", {})
        if saved != settings:
            raise InvalidInput(f"{out} was collected with other settings ({saved}); resume it with the same "
                               f"--ckpt/--round/--beta/--render, or collect into a new directory")
    cases_dir = None if verifier_cases is None else Path(verifier_cases)
    if cases_dir is not None:
        _check_cases_dir(cases_dir, settings)  # before any output exists, like the check above
    out.mkdir(parents=True, exist_ok=True)
    ann.mkdir(parents=True, exist_ok=True)
    if not info_path.is_file():
        info_path.write_text(json.dumps({"format": 1, "source": str((out / DATASET_DIR).resolve()), "backend": BACKEND,
                                         "horizon": ACTION_HORIZON, "dagger": settings}, indent=2) + "\n")
    summary = DaggerSummary()
    attempted = _attempted(out)
    with LeRobotWriter(out / DATASET_DIR, fps=4, image_size=config.image_size) as writer:
        jobs = []
        for spec in specs:
            todo = [e for e in range(episodes_per_task) if (suite, spec.task_id, e) not in attempted]
            summary.skipped += episodes_per_task - len(todo)
            jobs += [DaggerJob(suite, spec.task_id, e, round_, str(where), float(beta), render, config.image_size,
                               max_steps, teacher_check=teacher_check, verifier_cases=cases_dir is not None)
                     for e in todo]
        jobs.sort(key=lambda j: (j.episode, tasks.index(j.task_id)))  # every task about equally, early on
        if progress:
            progress(summary, len(jobs) + summary.skipped, advance=summary.skipped)

        if cases_dir is not None:
            _write_cases_info(cases_dir, settings, out, where, digest, render)

        def finish(job: DaggerJob, attempt: dict, episode: Episode | None, rows: list[dict]) -> None:
            cases = attempt.pop(CASES_KEY, None)
            if episode is not None:
                if cases_dir is not None and cases is not None:
                    # First, so a crash before the episode commits (its labels and attempt line) runs it again
                    # and replaces this same shard: one shard per recorded rollout, never a case twice.
                    from seal.verify import dataset as ds

                    ds.write_shard(cases_dir, ds.shard_name(job.suite, job.task_id, job.episode), cases["rows"])
                    summary.verifier_cases += len(cases["rows"])
                    summary.verifier_case_seconds = round(summary.verifier_case_seconds + cases["seconds"], 3)
                index = writer.add(episode)
                _write_labels(ann, index, episode, rows, LABELS_PATH, CHUNK_SIZE, ANNOTATIONS)
                summary.recorded += 1
                summary.frames += len(rows)
                summary.invalid_labels += sum(not r["valid"] for r in rows)
                summary.think_labels += sum(r["think"] for r in rows)
            summary.successes += attempt["success"]
            if "teacher_check" in attempt:
                summary.teacher_checks += 1
                summary.teacher_recovered += attempt["teacher_check"]["recovered"]
            summary.vla_done_early += attempt["ended"] == "vla_done"
            with open(out / ATTEMPTS, "a") as f:  # after the episode and its labels: a crash between redoes it
                f.write(json.dumps(attempt) + "\n")
            if progress:
                progress(summary, len(jobs) + summary.skipped, advance=1)

        if workers == 1:
            try:
                for job in jobs:
                    finish(*run_dagger_episode(job))
            finally:
                release_cached()
        else:
            from seal.sim.pool import ignore_interrupts

            with multiprocessing.get_context("spawn").Pool(workers, initializer=ignore_interrupts) as pool:
                for result in pool.imap_unordered(run_dagger_episode, jobs, chunksize=1):
                    finish(*result)
    (out / "dagger_summary.json").write_text(json.dumps(summarize(out) | {"settings": settings}, indent=2) + "\n")
    if cases_dir is not None:
        _write_cases_info(cases_dir, settings, out, where, digest, render, counts=True)
    return summary


def _cases_settings(settings: dict) -> dict:
    return {"source": BACKEND, **settings}


def _check_cases_dir(cases_dir: Path, settings: dict) -> None:
    """One cases directory per DAgger collection: its shards are named by (suite, task, episode) alone,
    so cases of another round, checkpoint or beta would overwrite them."""
    from seal.verify import dataset as ds

    if (cases_dir / "info.json").is_file():
        saved = ds.read_info(cases_dir).get("collection", {}).get("settings", {})
        if saved != _cases_settings(settings):
            raise InvalidInput(f"{cases_dir} holds verification cases made with other settings ({saved}); give each "
                               "DAgger collection a --verifier-cases directory of its own")
    elif cases_dir.is_dir() and any(cases_dir.iterdir()):
        raise InvalidInput(f"{cases_dir} is not empty and holds no verification cases (no info.json); "
                           "give --verifier-cases a new directory")


def _write_cases_info(cases_dir: Path, settings: dict, out: Path, where, digest: str, render: str, *,
                      counts: bool = False) -> None:
    """info.json of a DAgger collection's verification cases: what made them (the VLA's checkpoint and
    digest: a verifier trained on them names the policy whose states it saw) and, at the end of a run,
    counts over every shard so far (``counts``)."""
    from seal.verify import dataset as ds

    info = {"settings": _cases_settings(settings), "dagger_out": str(Path(out).resolve()), "policy": "vla",
            "vla_ckpt": str(where), "vla_ckpt_digest": digest,
            # the pixels' render model, the VLA's own (as `seal verify collect` records it for a learned VLA)
            "render_mode": render,
            "init_sources": {CASES_SOURCE: "DAgger starts: fresh sampled starts of the round's own seed namespace "
                                           "(seal.dagger.dagger_seed); init_index is the DAgger episode, init_seed "
                                           "the start's seed"},
            "cases": "think (the VLA's sub-plan end), vla_done and task_success (task-level), before_release "
                     "(a successful place's last closed-gripper state); every label the oracle's"}
    if (cases_dir / "info.json").is_file():
        old = ds.read_info(cases_dir).get("collection", {})
        info = {"counts": old["counts"]} | info if "counts" in old else info
    if counts:
        table = ds.read_cases(cases_dir, columns=["kind", "ended_by", "label"]).to_pydict()
        by: dict[str, dict[str, int]] = {}
        for key in ("kind", "ended_by"):
            for value, label in zip(table[key], table["label"]):
                cell = by.setdefault(key, {}).setdefault(value, {"success": 0, "failure": 0})
                cell["success" if label else "failure"] += 1
        info["counts"] = {"shards": len(ds.shard_paths(cases_dir)), "cases": len(table["label"]),
                          "success": sum(table["label"]), "failure": len(table["label"]) - sum(table["label"]), **by}
    ds.write_info(cases_dir, {"collection": info})


def summarize(out: Path) -> dict:
    """Figures over every episode a collection holds (all runs of it, not only the last)."""
    import pyarrow.parquet as pq

    from seal.annotate.pipeline import ANNOTATIONS

    out = Path(out)
    attempts, _ = read_jsonl(out / ATTEMPTS)
    frames = sum(a.get("frames", 0) for a in attempts)
    # checks with a whole budget of their own (the first ones of round 1 had only what the episode had left)
    checks = [a["teacher_check"] for a in attempts if "budget" in a.get("teacher_check", {})]
    why: dict[str, int] = {}
    think = 0
    ann = out / ANNOTATIONS_DIR
    for record in read_jsonl(ann / ANNOTATIONS)[0]:
        table = pq.read_table(ann / record["labels_path"], columns=["think", "valid", "why"]).to_pydict()
        think += sum(table["think"])
        for valid, reason in zip(table["valid"], table["why"]):
            if not valid:
                key = reason.split(":")[0][:60]
                why[key] = why.get(key, 0) + 1
    n = max(len(attempts), 1)
    measured = [a for a in attempts if a.get("subplan_accuracy") is not None]
    return {"episodes": len(attempts), "success": round(sum(a["success"] for a in attempts) / n, 4),
            "frames": frames, "think_labels": think, "invalid_labels": sum(why.values()), "why_invalid": why,
            "vla_done_early": sum(a.get("ended") == "vla_done" for a in attempts),
            # over the episodes that measured it (collections begun before the figure existed lack it)
            "subplan_accuracy": round(sum(a["subplan_accuracy"] * a["frames"] for a in measured)
                                      / max(sum(a["frames"] for a in measured), 1), 4) if measured else None,
            "teacher_checks": len(checks), "teacher_recovered": sum(c["recovered"] for c in checks),
            "teacher_unrecovered": [{"task": f"{a['suite']}/{a['task_id']}", "episode": a["init_index"],
                                     **a["teacher_check"]} for a in attempts
                                    if "budget" in a.get("teacher_check", {}) and not a["teacher_check"]["recovered"]]}



def _write_labels(ann: Path, index: int, episode: Episode, rows: list[dict], labels_path: str, chunk_size: int,
                  annotations: str) -> None:
    import os

    import pyarrow as pa
    import pyarrow.parquet as pq

    n = len(rows)
    table = pa.table({
        "episode_index": pa.array(np.full(n, index, np.int64)),
        "frame_index": pa.array(np.arange(n, dtype=np.int64)),
        "reasoning": pa.array([r["reasoning"] for r in rows]).dictionary_encode(),
        "now": pa.array([r["now"] for r in rows]).dictionary_encode(),
        "vla_reasoning": pa.array([r["vla_reasoning"] for r in rows]).dictionary_encode(),
        "vla_now": pa.array([r["vla_now"] for r in rows]).dictionary_encode(),
        "think": pa.array([r["think"] for r in rows], pa.bool_()),
        "valid": pa.array([r["valid"] for r in rows], pa.bool_()),
        "why": pa.array([r["why"] for r in rows]),
        "step": pa.array([r["step"] for r in rows], pa.int64()),
        "chunk": pa.array([r["chunk"].astype(np.float32).tolist() for r in rows], pa.list_(pa.float32(), PREDICT_HORIZON * 7)),
        "chunk_steps": pa.array([r["chunk_steps"] for r in rows], pa.int64()),
        "executed": pa.array([np.asarray(r["executed"], np.float32).reshape(-1).tolist() for r in rows],
                             pa.list_(pa.float32())),
    })
    rel = labels_path.format(chunk=index // chunk_size, episode=index)
    path = ann / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, path)
    record = {"episode_index": index, "status": "ok", "backend": BACKEND, "model": episode.meta["dagger"]["ckpt"],
              "instruction": episode.instruction, "length": n, "plans": list(episode.subplans),
              "critical_moments": [], "labels_path": rel, "error": None, "frame_labels": True,
              "start": [episode.meta["suite"], episode.meta["task_id"], episode.meta["init_index"]]}
    with open(ann / annotations, "a") as f:
        f.write(json.dumps(record) + "\n")
        f.flush()
        os.fsync(f.fileno())


def read_frame_labels(ann: Path, record: dict) -> dict[str, np.ndarray | list]:
    """A DAgger episode's per-frame labels: texts, think, valid, chunks (T, 16, 7) and how many of
    each chunk's steps are labels (`chunk_steps`)."""
    import pyarrow.parquet as pq

    table = pq.read_table(Path(ann) / record["labels_path"]).to_pydict()
    chunks = np.asarray(table["chunk"], np.float32).reshape(-1, PREDICT_HORIZON, 7)
    # Collections before closed-loop labels stored the expert's one-shot extrapolation: only its
    # first ACTION_HORIZON steps are what the expert executes, so only those are trained on.
    steps = np.asarray(table.get("chunk_steps", [ACTION_HORIZON] * len(chunks)), np.int64)
    # Collections before this column did not keep the executed actions (None: unknown, not "none").
    executed = [np.asarray(a, np.float32).reshape(-1, 7) for a in table["executed"]] if "executed" in table else None
    return {"chunk_steps": steps, "executed": executed, "reasoning": table["reasoning"], "vla_reasoning": table["vla_reasoning"], "now": table["now"],
            "think": np.asarray(table["think"], bool), "valid": np.asarray(table["valid"], bool), "chunks": chunks}


def unrecovered_sheet(out: Path, png: Path, limit: int = 12) -> Path | None:
    """A contact sheet of the states the teacher could not finish from (agent and wrist view as the
    VLA saw them, the task, the step and the sub-plan in force): what the expert cannot handle."""
    from PIL import Image, ImageDraw

    from seal.annotate.pipeline import ANNOTATIONS
    from seal.datasets import open_dataset
    from seal.datasets.lerobot import AGENT_VIDEO_KEY, WRIST_VIDEO_KEY

    out = Path(out)
    records, _ = read_jsonl(out / ANNOTATIONS_DIR / ANNOTATIONS)
    episode_of = {tuple(r["start"]): r["episode_index"] for r in records if "start" in r}
    reader = open_dataset(out / DATASET_DIR)
    tiles = []
    for u in summarize(out)["teacher_unrecovered"][:limit]:
        suite, task = u["task"].split("/")
        e = episode_of.get((suite, int(task), u["episode"]))
        if e is None:
            continue
        views = [reader.video(e, key)[u["frame"]] for key in (AGENT_VIDEO_KEY, WRIST_VIDEO_KEY)]
        image = Image.fromarray(np.concatenate(views, axis=1)).resize((512, 256), Image.NEAREST)
        tile = Image.new("RGB", (512, 280), "white")
        tile.paste(image, (0, 24))
        ImageDraw.Draw(tile).text((4, 4), f"{u['task']} #{u['episode']}, step {u['from_step']}: {u['now']}", fill="black")
        tiles.append(tile)
    if not tiles:
        return None
    sheet = Image.new("RGB", (1024, 280 * ((len(tiles) + 1) // 2)), "white")
    for i, tile in enumerate(tiles):
        sheet.paste(tile, ((i % 2) * 512, (i // 2) * 280))
    sheet.save(png)
    return Path(png)
