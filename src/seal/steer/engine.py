"""SEAL's steering loop, one episode at a time.

For each sub-plan the policy writes:

  HYPOTHESIZE  the policy samples K candidates (rows of one batched ``act`` call per chunk);
  PREDICT      each candidate runs closed-loop in its own pool slot, chunk by chunk, until the
               policy emits <think> or the sub-plan's step budget is spent;
  VERIFY       a finished candidate goes to the verifier in the background while the others
               keep sampling; the first verdict of success ends the round (early exit);
  COMMIT       every slot is moved to the winner's end state (``sync`` mode), or the winner's
               actions are executed in a separate evaluation world (``replay`` mode) and every
               slot is moved to what really happened there.

A policy that never emits <think> (``policy.thinks`` is False: a plain pi0 server, whose
sub-plans come from an external planner) cannot say when its sub-plan is done. For it, the
verifier also checks each candidate every ``check_every`` steps in the background; the first
check that passes ends the candidate at that point (``ended_by="verified"``), so a sub-plan ends
when the verifier accepts or on its step budget.

If no candidate passes, the round is resampled (up to ``rounds`` rounds); then the candidate
with the best verifier score wins, and if no verifier gave a score, the first candidate.

Methods share this loop: ``base`` (K=1, nothing verified: the policy alone), ``random`` (a
random finished candidate), ``value`` (V-GPS: at every chunk, K sampled chunks are ranked by a
scorer Q(obs, chunk, goal text) and the best one is executed; the goal text is the task or the
sub-plan), ``seal`` (verified, early exit).
"""

from __future__ import annotations

import time
from concurrent.futures import Future
from dataclasses import dataclass, field

import numpy as np

from seal.errors import InvalidInput
from seal.policies.base import ACTION_HORIZON, Reasoning
from seal.sim.observation import Observation
from seal.sim.snapshot import Snapshot
from seal.steer.background import BackgroundVerifier
from seal.steer.trace import Trace
from seal.verify.base import Verdict, VerifyRequest

METHODS = ("base", "random", "value", "seal")
VALUE_GOALS = ("task", "subplan")
MODES = ("sync", "replay")


@dataclass(frozen=True)
class SteerConfig:
    method: str = "seal"
    k: int = 10
    rounds: int = 2  # sampling rounds per sub-plan before the fallback picks a candidate
    subplan_budget: int = 200  # control steps one candidate may spend on one sub-plan
    mode: str = "sync"
    max_steps: int | None = None  # default: the suite's limit (520 for LIBERO-10)
    seed: int = 0
    value_goal: str = "task"  # value method: what the scorer is conditioned on (V-GPS uses the task)
    check_every: int = 20  # policies that never think: steps between mid-rollout verifier checks

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise InvalidInput(f"unknown method {self.method!r}; valid: {', '.join(METHODS)}")
        if self.value_goal not in VALUE_GOALS:
            raise InvalidInput(f"unknown value goal {self.value_goal!r}; valid: {', '.join(VALUE_GOALS)}")
        if self.mode not in MODES:
            raise InvalidInput(f"unknown mode {self.mode!r}; valid: {', '.join(MODES)}")
        if self.k < 1 or self.rounds < 1 or self.subplan_budget < ACTION_HORIZON or self.check_every < ACTION_HORIZON:
            raise InvalidInput(f"need k >= 1, rounds >= 1, subplan_budget >= {ACTION_HORIZON}, check_every >= "
                               f"{ACTION_HORIZON}; got k={self.k}, rounds={self.rounds}, "
                               f"subplan_budget={self.subplan_budget}, check_every={self.check_every}")

    @property
    def effective_k(self) -> int:
        return 1 if self.method == "base" else self.k


@dataclass
class Candidate:
    round: int
    slot: int
    actions: list = field(default_factory=list)  # executed (5-step) chunks, in order
    steps: int = 0
    snapshot: Snapshot | None = None
    ended_by: str = ""  # think | budget | step_limit | task_success | verified | error
    error: str | None = None
    verdict: Verdict | None = None
    future: Future | None = None
    t_start: float = 0.0
    t_end: float = 0.0
    t_verified: float = 0.0
    checks: list = field(default_factory=list)  # mid-rollout checks of a policy that never thinks


@dataclass
class _Check:
    """A verification of a candidate's state part-way through its rollout."""

    future: Future
    snapshot: Snapshot
    chunks: int  # executed chunks up to this point
    steps: int
    verdict: Verdict | None = None


@dataclass
class SteerResult:
    task: str
    instruction: str
    init_index: int
    method: str
    success: bool = False
    sim_error: bool = False
    steps: int = 0
    wall_s: float = 0.0
    subplans: list[str] = field(default_factory=list)
    goal_status: dict = field(default_factory=dict)
    verifier_calls: int = 0
    input_tokens: int = 0
    output_tokens: int = 0
    cost_usd: float = 0.0
    rounds: int = 0
    fallbacks: int = 0
    verifier_errors: int = 0  # verifications that got no answer (transient errors past their retries)
    verifier_unavailable: bool = False  # in most rounds that asked the verifier, it never answered
    divergence: list[float] = field(default_factory=list)  # replay mode: per commit, max |qpos| gap
    timing: dict = field(default_factory=lambda: {"sampling_s": 0.0, "predict_s": 0.0, "verify_wait_s": 0.0})
    executed_actions: list = field(default_factory=list)
    trace: str = ""


class Steerer:
    """Runs steered episodes of one task on an `EnvPool` of at least K slots."""

    def __init__(self, pool, policy, verifier, config: SteerConfig, *, eval_world=None, trace: Trace | None = None,
                 grid_dir=None, scorer=None):
        if config.method == "seal" and verifier is None:
            raise InvalidInput("method 'seal' needs a verifier (e.g. --verifier oracle)")
        if config.method == "value" and scorer is None:
            raise InvalidInput("method 'value' needs a chunk scorer (a trained V-GPS Q-function)")
        self.scorer = scorer
        if pool.k < config.effective_k:
            raise InvalidInput(f"the pool has {pool.k} slots but method {config.method!r} needs k={config.effective_k}")
        if config.mode == "replay" and eval_world is None:
            raise InvalidInput("replay mode needs an evaluation world to execute the winner's actions in")
        self.pool, self.policy, self.config, self.trace = pool, policy, config, trace
        self.verifier = verifier
        self.eval_world = eval_world
        self.grid_dir = grid_dir  # write a candidate contact sheet per round here (costs K renders)
        self._subplan_index = 0
        self._rng = np.random.default_rng(config.seed)
        self._atoms = policy.privileged_atoms() if hasattr(policy, "privileged_atoms") else None
        self._needs_images = self._atoms is None  # a real VLA looks at images; the expert does not
        # A policy without <think> (plain pi0 + a planner): the verifier decides when a sub-plan is done.
        self._check_midway = config.method == "seal" and not getattr(policy, "thinks", True)

    # ---- the episode ------------------------------------------------------------------------
    def run(self, init_index: int) -> SteerResult:
        cfg, pool = self.config, self.pool
        max_steps = cfg.max_steps or pool.task.max_steps
        start = time.perf_counter()
        result = SteerResult(task=pool.task.key, instruction=pool.task.instruction, init_index=init_index,
                             method=cfg.method)
        self._result = result
        committed = pool.reset(init_index)
        if self.eval_world is not None:
            self.eval_world.reset(init_index)
        self.policy.reset(pool.task.instruction, seed=cfg.seed * 100_003 + init_index)
        scene = self._observe(0, images=False, atoms=[]).scene  # names only, for grounding
        self._objects = sorted(set(scene.bodies) | set(scene.sites))
        idle = 0
        background = BackgroundVerifier(self.verifier) if self.verifier is not None else None
        try:
            while committed.steps < max_steps:
                obs = self._observe(0, images=self._needs_images or self._verifier_images(), atoms=self._atoms)
                reasoning = self.policy.reason(obs)
                if not result.subplans:
                    result.subplans = list(reasoning.plans)
                if reasoning.finished:
                    break
                self._subplan_index += 1
                self._emit("subplan", step=committed.steps, text=reasoning.now, reasoning=reasoning.text())
                winner = self._steer_subplan(committed, obs, reasoning, max_steps, background, result)
                if winner is None:  # every candidate hit a simulator error
                    result.sim_error = True
                    break
                committed = self._commit(winner, committed, result)
                task_done = pool.check([str(a) for a in self._goal_atoms()], slots=[0])[0]
                if all(task_done.values()):
                    break
                # A policy that keeps switching to <think> without acting would loop forever.
                idle = idle + 1 if winner.steps == 0 else 0
                if idle > len(result.subplans) + 2:
                    break
        finally:
            if background is not None:
                background.close()
                result.verifier_errors = background.errors
                result.verifier_unavailable = background.mostly_unavailable
        status = pool.check([str(a) for a in self._goal_atoms()], slots=[0])[0]
        result.goal_status = status
        result.success = bool(status) and all(status.values()) and not result.sim_error
        result.steps = committed.steps
        result.wall_s = round(time.perf_counter() - start, 3)
        self._emit("episode_end", success=result.success, steps=result.steps, sim_error=result.sim_error,
                   verifier_calls=result.verifier_calls, verifier_errors=result.verifier_errors,
                   verifier_unavailable=result.verifier_unavailable, fallbacks=result.fallbacks)
        return result

    # ---- one sub-plan: rounds of K candidates --------------------------------------------------
    def _steer_subplan(self, committed, obs0, reasoning, max_steps, background, result) -> Candidate | None:
        cfg = self.config
        if cfg.method == "value":
            return self._value_subplan(committed, obs0, reasoning, max_steps, result)
        rounds = 1 if cfg.method in ("base", "random") else cfg.rounds
        tried: list[Candidate] = []
        for r in range(rounds):
            result.rounds += 1
            cands, winner = self._round(r, committed, obs0, reasoning, max_steps, background, result)
            tried += cands
            if winner is not None:
                return winner
        usable = [c for c in tried if c.error is None and c.snapshot is not None]
        if not usable:
            return None
        result.fallbacks += cfg.method == "seal"
        if cfg.method == "random":
            return usable[int(self._rng.integers(len(usable)))]
        scored = [c for c in usable if c.verdict is not None and c.verdict.score is not None]
        return max(scored, key=lambda c: c.verdict.score) if scored else usable[0]

    def _value_subplan(self, committed, obs0, reasoning, max_steps, result) -> Candidate | None:
        """V-GPS: sample K chunks from one state, execute the one the scorer rates best, repeat."""
        cfg, k = self.config, self.config.k
        goal = self.pool.task.instruction if cfg.value_goal == "task" else reasoning.now
        self.pool.sync(committed)
        self.policy.begin(k)
        c = Candidate(round=0, slot=0, snapshot=committed, t_start=time.perf_counter())
        obs = obs0
        while True:
            t0 = time.perf_counter()
            chunks = self.policy.act([obs] * k, reasoning, rows=list(range(k)))
            acting = [i for i, ch in enumerate(chunks) if not ch.think]
            end = ("think" if len(acting) <= k // 2 else "budget" if c.steps >= cfg.subplan_budget
                   else "step_limit" if committed.steps + c.steps >= max_steps else "")
            if end:  # most samples say the sub-plan is done: the policy would think now
                c.ended_by, c.t_end = end, time.perf_counter()
                break
            scores = np.asarray(self.scorer.score(obs, np.stack([chunks[i].actions for i in acting]), goal))
            best = acting[int(np.argmax(scores))]
            result.timing["sampling_s"] += time.perf_counter() - t0
            t0 = time.perf_counter()
            chunk = np.clip(chunks[best].actions[:ACTION_HORIZON], -1.0, 1.0)
            res = self.pool.step({0: chunk}, observe=True, images=self._needs_images or self.scorer_needs_images,
                                 privileged_atoms=self._atoms, stop_on_success=True)[0]
            result.timing["predict_s"] += time.perf_counter() - t0
            if not res.ok:
                c.error, c.ended_by = res.error or "sim_error", "error"
                return None
            c.actions.append(chunk[: res.steps])
            c.steps += res.steps
            c.snapshot, obs = res.snapshot, res.observation
            if res.success:
                c.ended_by, c.t_end = "task_success", time.perf_counter()
                break
        self._emit("candidate", round=0, slot=0, steps=c.steps, ended_by=c.ended_by, error=c.error,
                   snapshot=c.snapshot.id, verdict=None, t_start=c.t_start, t_end=c.t_end, t_verified=0.0)
        return c

    @property
    def scorer_needs_images(self) -> bool:
        return bool(getattr(self.scorer, "needs_images", True))

    def _round(self, r, committed, obs0, reasoning, max_steps, background, result):
        cfg, pool = self.config, self.pool
        k = cfg.effective_k
        pool.sync(committed)
        self.policy.begin(k)
        if background is not None:
            background.start_round()  # so a round decided without any verdict can be told apart
        now = time.perf_counter()
        cands = [Candidate(round=r, slot=i, snapshot=committed, t_start=now) for i in range(k)]
        obs = {i: obs0 for i in range(k)}
        active = list(range(k))
        winner = None
        while active and winner is None:
            t0 = time.perf_counter()
            chunks = self.policy.act([obs[i] for i in active], reasoning, rows=active)
            result.timing["sampling_s"] += time.perf_counter() - t0
            to_step = {}
            for i, chunk in zip(list(active), chunks):
                c = cands[i]
                end = ("think" if chunk.think else "budget" if c.steps >= cfg.subplan_budget
                       else "step_limit" if committed.steps + c.steps >= max_steps else "")
                if end:
                    self._finish(c, end, obs0, reasoning, background, result)
                    active.remove(i)
                else:
                    to_step[i] = np.clip(chunk.actions[:ACTION_HORIZON], -1.0, 1.0)
            if to_step:
                t0 = time.perf_counter()
                stepped = pool.step(to_step, observe=True, images=self._needs_images, privileged_atoms=self._atoms,
                                    stop_on_success=True)
                result.timing["predict_s"] += time.perf_counter() - t0
                for res in stepped:
                    c = cands[res.slot]
                    if not res.ok:
                        c.error, c.ended_by = res.error or "sim_error", "error"
                        active.remove(res.slot)
                        continue
                    c.actions.append(to_step[res.slot][: res.steps])
                    c.steps += res.steps
                    c.snapshot = res.snapshot
                    obs[res.slot] = res.observation
                    if res.success:  # the whole task holds: nothing left to verify against
                        self._finish(c, "task_success", obs0, reasoning, background, result)
                        active.remove(res.slot)
                    elif self._check_midway and c.steps >= (len(c.checks) + 1) * cfg.check_every:
                        c.checks.append(_Check(background.submit(self._request(c, obs0, reasoning)), c.snapshot,
                                               len(c.actions), c.steps))
                        result.verifier_calls += 1
            if self._check_midway:
                self._take_checks(cands, active)
            winner = self._first_pass(cands)
        if winner is None:
            winner = self._wait_for_verdicts(cands, result)
        for c in cands:  # early exit: rollouts and verifications still running are no longer needed
            if not c.ended_by:
                c.ended_by = "stopped"
            if c.future is not None and not c.future.done():
                c.future.cancel()
            for chk in c.checks:
                if chk.verdict is None and chk.future.done() and not chk.future.cancelled():
                    chk.verdict = chk.future.result()
                    self._account(chk.verdict)
                elif not chk.future.done():
                    chk.future.cancel()
        if self.grid_dir is not None:
            self._grid(r, cands, reasoning)
        for c in cands:
            self._emit("candidate", round=r, slot=c.slot, steps=c.steps, ended_by=c.ended_by, error=c.error,
                       snapshot=c.snapshot.id if c.snapshot else None,
                       verdict=_verdict_dict(c.verdict), t_start=c.t_start, t_end=c.t_end, t_verified=c.t_verified)
        return cands, winner

    def _finish(self, c: Candidate, how: str, obs0, reasoning, background, result) -> None:
        """A candidate ended: hand it to the verifier (seal) or mark it done (base/random)."""
        c.ended_by, c.t_end = how, time.perf_counter()
        if self.config.method != "seal":
            return
        if how == "task_success":  # LIBERO's own success check passed in this candidate's world
            c.verdict = Verdict(True, "the task's goal holds", score=1.0)
            c.t_verified = c.t_end
            return
        c.future = background.submit(self._request(c, obs0, reasoning))
        result.verifier_calls += 1

    def _request(self, c: Candidate, obs0, reasoning) -> VerifyRequest:
        """What the verifier judges: the sub-plan and the candidate's slot as it is now."""
        request = VerifyRequest(subplan=reasoning.now, instruction=self.pool.task.instruction, plans=reasoning.plans,
                                index=reasoning.plans.index(reasoning.now) if reasoning.now in reasoning.plans else None,
                                first_agent=obs0.agent, task=self.pool.task.key, candidate=c.slot)
        atoms = self.verifier.atoms_needed(request, self._objects)
        final = self._observe(c.slot, images=self.verifier.needs_images, atoms=atoms)
        request.scene, request.final_agent, request.final_wrist = final.scene, final.agent, final.wrist
        return request

    def _take_checks(self, cands: list[Candidate], active: list[int]) -> None:
        """A passed mid-rollout check ends its candidate at the checked point (the later chunks,
        already run in its slot, are dropped: the commit syncs to the checked snapshot)."""
        for i in list(active):
            c = cands[i]
            for chk in c.checks:
                if chk.verdict is None and chk.future.done():
                    chk.verdict = chk.future.result()
                    self._account(chk.verdict)
                if chk.verdict is not None and chk.verdict.passed:
                    c.actions, c.steps, c.snapshot = c.actions[: chk.chunks], chk.steps, chk.snapshot
                    c.verdict, c.ended_by = chk.verdict, "verified"
                    c.t_end = c.t_verified = time.perf_counter()
                    active.remove(i)
                    break

    def _first_pass(self, cands: list[Candidate]) -> Candidate | None:
        method = self.config.method
        if method == "base":
            return cands[0] if cands[0].ended_by and cands[0].error is None else None
        if method == "random":
            return None  # decided once every candidate has ended
        passed = []
        for c in cands:
            if c.future is not None and c.future.done() and c.verdict is None:
                self._take_verdict(c)
            if c.verdict is not None and c.verdict.passed:
                passed.append(c)
        return min(passed, key=lambda c: c.t_verified) if passed else None

    def _wait_for_verdicts(self, cands, result) -> Candidate | None:
        if self.config.method != "seal":
            return None
        t0 = time.perf_counter()
        for c in sorted((c for c in cands if c.future is not None and c.verdict is None), key=lambda c: c.t_end):
            self._take_verdict(c)
            if c.verdict.passed:
                break
        result.timing["verify_wait_s"] += time.perf_counter() - t0
        return self._first_pass(cands)

    def _take_verdict(self, c: Candidate) -> None:
        """Collect a finished verification; every call is paid for, winner or not."""
        c.verdict, c.t_verified = c.future.result(), time.perf_counter()
        self._account(c.verdict)

    def _account(self, verdict: Verdict) -> None:
        self._result.input_tokens += verdict.input_tokens
        self._result.output_tokens += verdict.output_tokens
        self._result.cost_usd += verdict.cost_usd

    # ---- commit ----------------------------------------------------------------------------
    def _commit(self, winner: Candidate, committed: Snapshot, result: SteerResult) -> Snapshot:
        actions = np.concatenate(winner.actions) if winner.actions else np.zeros((0, 7))
        result.executed_actions.extend(actions.tolist())
        target = winner.snapshot
        if self.config.mode == "replay":
            # Execute as a real robot would, then trust what happened over what was predicted.
            if len(actions):
                self.eval_world.step_chunk(actions)
            real = self.eval_world.snapshot()
            nq = self.eval_world.model.nq
            gap = float(np.abs(real.physics[1 : 1 + nq] - target.physics[1 : 1 + nq]).max())
            result.divergence.append(gap)
            target = real
        self.pool.sync(target)
        self._emit("commit", slot=winner.slot, round=winner.round, steps=target.steps, snapshot=target.id,
                   ended_by=winner.ended_by, verdict=_verdict_dict(winner.verdict))
        return target

    def _grid(self, r: int, cands: list[Candidate], reasoning: Reasoning) -> None:
        from pathlib import Path

        from seal.sim.observation import to_policy_image
        from seal.steer.grid import candidate_grid

        shown = [c for c in cands if c.snapshot is not None]
        views = self.pool.render(("agentview",), slots=[c.slot for c in shown])  # slots still hold end states
        labels = [f"#{c.slot} {c.steps} steps, {c.ended_by}" for c in shown]
        verdicts = [c.verdict.success if c.verdict is not None else None for c in shown]
        candidate_grid([to_policy_image(v["agentview"]) for v in views], labels, verdicts,
                       Path(self.grid_dir) / f"subplan{self._subplan_index:02d}_round{r}.png",
                       title=f"{reasoning.now} (round {r})")

    # ---- small helpers ------------------------------------------------------------------------
    def _observe(self, slot: int, *, images: bool, atoms) -> Observation:
        return self.pool.observe([slot], images=images, privileged_atoms=atoms)[0]

    def _verifier_images(self) -> bool:
        """Whether the judge of this method (verifier or value scorer) looks at the frame."""
        if self.config.method == "value":
            return self.scorer is not None and self.scorer_needs_images
        return self.verifier is not None and self.config.method == "seal" and self.verifier.needs_images

    def _goal_atoms(self) -> list[str]:
        return [str(a) for a in self.pool.task.goal_atoms()]

    def _emit(self, event: str, **fields) -> None:
        if self.trace is not None:
            self.trace.write(event, **fields)


def _verdict_dict(v: Verdict | None) -> dict | None:
    if v is None:
        return None
    return {"success": v.success, "rationale": v.rationale, "latency_s": round(v.latency_s, 4),
            "score": v.score, "cached": bool(v.extra.get("cached", False)), "error": v.extra.get("error")}
