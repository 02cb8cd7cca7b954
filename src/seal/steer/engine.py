"""SEAL's steering loop, one episode at a time.

For each sub-plan the policy writes:

  HYPOTHESIZE  the policy samples K candidates (rows of one batched ``act`` call per chunk);
  PREDICT      each candidate runs closed-loop in its own pool slot, chunk by chunk, until the
               policy emits <think> or the sub-plan's step budget is spent;
  VERIFY       a finished candidate goes to the verifier in the background while the others
               keep sampling; the first verdict of success ends the round (early exit);
               ``verify_order="slot"`` (the default) takes the verdicts at each chunk boundary, in
               candidate order, so "first" is decided by the seeds; ``"arrival"`` takes them as they
               come in (thread timing can then decide which candidate is first);
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

Methods share this loop and differ only in their candidate selection (`seal.steer.selection`):
``base`` (K=1, nothing verified: the policy alone), ``random`` (a random finished candidate),
``value`` (V-GPS: at every chunk, K sampled chunks are ranked by a scorer Q(obs, chunk, goal
text) and the best one is executed; the goal text is the task or the sub-plan), ``seal``
(verified, early exit). The loop never asks which method it runs.

What happens is published as events (``subplan``, ``verify_request``, ``candidate``, ``round_end``,
``commit``, ``episode_end``) to subscribers (`seal.steer.events`): the trace, the candidate grids and
progress displays listen; the loop writes no file itself.
"""

from __future__ import annotations

import time

import numpy as np

from seal.errors import InvalidInput
from seal.policies.base import ACTION_HORIZON, ActionChunk, Reasoning, images_for
from seal.sim.observation import Observation
from seal.sim.snapshot import Snapshot
from seal.steer.background import BackgroundVerifier
from seal.steer.config import SteerConfig
from seal.steer.events import GridWriter, Subscriber
from seal.steer.result import SteerResult
from seal.steer.scoring import scoring_images, scoring_view
from seal.steer.selection import Candidate, Check, Subplan
from seal.steer.trace import Trace
from seal.verify.base import Verdict, VerifyRequest
from seal.verify.oracle import checked_atoms, ground

__all__ = ["Steerer"]


class Steerer:
    """Runs steered episodes of one task on an `EnvPool` of at least K slots.

    ``trace`` and ``grid_dir`` are shorthands for the two usual subscribers; ``subscribers``
    adds any others (progress displays, tests).
    """

    def __init__(self, pool, policy, verifier, config: SteerConfig, *, eval_world=None, trace: Trace | None = None,
                 grid_dir=None, scorer=None, subscribers: tuple[Subscriber, ...] = ()):
        self.selection = config.selection()
        self.selection.check(verifier, scorer)
        self.scorer = scorer
        k = self.selection.k(config)
        if pool.k < k:
            raise InvalidInput(f"the pool has {pool.k} slots but method {config.method!r} needs k={k}")
        if config.mode == "replay" and eval_world is None:
            raise InvalidInput("replay mode needs an evaluation world to execute the winner's actions in")
        self.pool, self.policy, self.config, self.trace = pool, policy, config, trace
        self.verifier = verifier
        self.eval_world = eval_world
        self.subscribers: list[Subscriber] = [s for s in (trace,) if s is not None]
        if grid_dir is not None:  # a candidate contact sheet per round (costs K renders)
            self.subscribers.append(GridWriter(pool, grid_dir))
        self.subscribers += list(subscribers)
        self._subplan_index = 0
        self._taken = 0  # verdicts taken so far: which candidate passed "first" is counted, never timed
        self._boundary: list = []  # slot order: (request, candidate or check) to verify at this chunk boundary
        self.rng = np.random.default_rng(config.seed)
        self.atoms = policy.privileged_atoms()
        # What the policy looks at: nothing (the scripted expert reads state), openpi's 224-px
        # view (True), or both cameras rendered at the size the policy was trained at.
        # A policy that declares an image size gets its renders even if it also reads state.
        self.policy_images: bool | int = images_for(policy, self.atoms)
        # A policy without <think> (plain pi0 + a planner): the verifier decides when a sub-plan is done.
        self._check_midway = self.selection.verifies and not policy.thinks

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
        episode_first = None  # the agent view at the episode's start: "before" of a task-level check
        result.ended_by = "step_limit"  # unless something below ends it first
        background = BackgroundVerifier(self.verifier) if self.verifier is not None else None
        try:
            while committed.steps < max_steps:
                judge_images = self.selection.judge_needs_images(self.verifier, self.scorer)
                obs = self._observe(0, images=self.policy_images or judge_images, atoms=self.atoms)
                first_agent = obs.agent
                if judge_images and self.selection.verifies and self.policy_images is not True and self.policy_images:
                    # the policy's small view is not what a VLM judges: its "before" image at 224 too
                    first_agent = self._observe(0, images=True, atoms=None).agent
                episode_first = first_agent if episode_first is None else episode_first
                reasoning = self.policy.reason(obs)
                if not result.subplans:
                    result.subplans = list(reasoning.plans)
                if reasoning.finished:
                    reopened = self._check_done(reasoning, episode_first, committed.steps, background, result)
                    if reopened is None:
                        result.ended_by, result.last_reasoning = "policy_finished", reasoning.text()
                        break
                    reasoning = reopened
                self._subplan_index += 1
                self.emit("subplan", step=committed.steps, text=reasoning.now, reasoning=reasoning.text())
                sub = Subplan(self._subplan_index, committed, obs, reasoning, max_steps, background, result,
                              first_agent=first_agent)
                winner = self.selection.run_subplan(self, sub)
                if winner is None:  # every candidate hit a simulator error
                    result.sim_error, result.ended_by = True, "sim_error"
                    break
                committed = self._commit(winner, committed, result, reasoning)
                task_done = pool.check([str(a) for a in self._goal_atoms()], slots=[0])[0]
                if all(task_done.values()):
                    result.ended_by = "goal_holds"
                    break
                # A policy that keeps switching to <think> without acting would loop forever.
                idle = idle + 1 if winner.steps == 0 else 0
                if idle > len(result.subplans) + 2:
                    result.ended_by = "idle"
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
        self.emit("episode_end", success=result.success, steps=result.steps, sim_error=result.sim_error,
                  ended_by=result.ended_by, **({"reasoning": result.last_reasoning} if result.last_reasoning else {}),
                  verifier_calls=result.verifier_calls, verifier_errors=result.verifier_errors,
                  verifier_unavailable=result.verifier_unavailable, fallbacks=result.fallbacks)
        return result

    def _check_done(self, reasoning: Reasoning, first_agent, step: int, background: BackgroundVerifier | None,
                    result: SteerResult) -> Reasoning | None:
        """The policy wrote that the task is complete. Methods that verify ask the verifier whether
        the instruction holds in the committed state (``done_check="verify"``). None: the episode
        ends (the verifier agrees, cannot tell, or the method trusts the policy). Otherwise the
        reasoning the policy goes back to: its last claimed sub-plan, undone, the likeliest to have
        slipped (an object held over its target, a mug short of the microwave); its first sub-plan
        when it claims the task complete with nothing done (the learned VLA writes that too)."""
        if background is None or not self.selection.verifies or self.config.done_check != "verify":
            return None
        if not reasoning.done and not reasoning.plans:
            return None  # no plan at all: there is no sub-plan to go back to
        instruction = self.pool.task.instruction
        request = VerifyRequest(subplan=instruction, instruction=instruction, plans=reasoning.plans,
                                first_agent=first_agent, task=self.pool.task.key,
                                goal_atoms=tuple(self._goal_atoms()))
        final = self._observe(0, images=self.verifier.needs_images, atoms=self.verifier.atoms_needed(request, self._objects))
        request.scene, request.final_agent, request.final_wrist = final.scene, final.agent, final.wrist
        # published like a candidate's request, so case collectors keep task-level cases too
        self.emit("verify_request", request=request, subplan=self._subplan_index, round=0, slot=0, steps=0,
                  ended_by="done_check")
        result.verifier_calls += 1
        t0 = time.perf_counter()
        verdict = background.submit(request).result()
        result.timing["verify_wait_s"] += time.perf_counter() - t0
        refused = verdict.success is False  # unknown: the verifier cannot overrule the policy without evidence
        result.done_checks.append(not refused)
        reopened = None
        if refused:
            reopened = (Reasoning(reasoning.plans, reasoning.done[:-1], reasoning.done[-1]) if reasoning.done
                        else Reasoning(reasoning.plans, (), reasoning.plans[0]))
        self.emit("done_check", step=step, reasoning=reasoning.text(), verdict=_verdict_dict(verdict),
                  refused=refused, **({"back_to": reopened.now} if reopened else {}))
        return reopened

    # ---- one round of K candidates -------------------------------------------------------------
    def run_round(self, sub: Subplan, r: int) -> Candidate | None:
        """K candidates from the committed state until one wins or all end; returns the winner."""
        cfg, pool, result = self.config, self.pool, sub.result
        k = self.selection.k(cfg)
        self.begin(sub, k)
        if sub.background is not None:
            sub.background.start_round()  # so a round decided without any verdict can be told apart
        now = time.perf_counter()
        cands = [Candidate(round=r, slot=i, snapshot=sub.committed, t_start=now) for i in range(k)]
        sub.tried += cands
        self._boundary = []
        obs = {i: sub.obs0 for i in range(k)}
        active = list(range(k))
        winner = None
        while active and winner is None:
            t0 = time.perf_counter()
            chunks = self.policy.act([obs[i] for i in active], sub.reasoning, rows=active)
            result.timing["sampling_s"] += time.perf_counter() - t0
            to_step = {}
            for i, chunk in zip(list(active), chunks):
                c = cands[i]
                end = ("think" if chunk.think else "budget" if c.steps >= cfg.subplan_budget
                       else "step_limit" if sub.committed.steps + c.steps >= sub.max_steps else "")
                if end:
                    self._finish(c, end, sub)
                    active.remove(i)
                else:
                    to_step[i] = np.clip(chunk.actions[:ACTION_HORIZON], -1.0, 1.0)
            if to_step:
                t0 = time.perf_counter()
                stepped = pool.step(to_step, observe=True, images=self.policy_images, privileged_atoms=self.atoms,
                                    stop_on_success=True)
                result.timing["predict_s"] += time.perf_counter() - t0
                _add_worker_times(result, stepped)
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
                        self._finish(c, "task_success", sub)
                        active.remove(res.slot)
                    elif self._check_midway and c.steps >= (len(c.checks) + 1) * cfg.check_every:
                        chk = Check(None, c.snapshot, len(c.actions), c.steps)
                        c.checks.append(chk)
                        self._verify(self._request(c, sub), chk, sub)
            if self._in_slot_order:  # this boundary's requests, as one group (one batch for a batching verifier)
                self._submit_boundary(sub.background)
            if self._check_midway:
                self._take_checks(cands, active, result)
            if self._in_slot_order:  # this chunk boundary is settled before the next chunk is sampled
                self._settle(cands, result)
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
        # The slots still hold the candidates' end states here: a grid subscriber renders them now.
        self.emit("round_end", subplan=sub.index, round=r, candidates=cands, reasoning=sub.reasoning)
        for c in cands:
            self.emit("candidate", round=r, slot=c.slot, steps=c.steps, ended_by=c.ended_by, error=c.error,
                      snapshot=c.snapshot.id if c.snapshot else None,
                      verdict=_verdict_dict(c.verdict), t_start=c.t_start, t_end=c.t_end, t_verified=c.t_verified)
        return winner

    def _finish(self, c: Candidate, how: str, sub: Subplan) -> None:
        """A candidate ended: hand it to the verifier (methods that verify) or just mark it done."""
        c.ended_by, c.t_end = how, time.perf_counter()
        if not self.selection.verifies:
            return
        if how == "task_success":  # LIBERO's own success check passed in this candidate's world
            c.verdict = Verdict(True, "the task's goal holds", score=1.0)
            c.t_verified, c.taken = c.t_end, self._next_taken()
            return
        self._verify(self._request(c, sub), c, sub)

    def _verify(self, request: VerifyRequest, owner: Candidate | Check, sub: Subplan) -> None:
        """Send ``request`` to the verifier now (arrival order) or with the rest of this chunk
        boundary (slot order); ``owner.future`` will hold its verdict."""
        sub.result.verifier_calls += 1
        if self._in_slot_order:
            self._boundary.append((request, owner))
        else:
            owner.future = sub.background.submit(request)

    def _submit_boundary(self, background: BackgroundVerifier) -> None:
        if self._boundary:
            futures = background.submit_together([request for request, _ in self._boundary])
            for (_, owner), future in zip(self._boundary, futures):
                owner.future = future
            self._boundary = []

    def _request(self, c: Candidate, sub: Subplan) -> VerifyRequest:
        """What the verifier judges: the sub-plan and the candidate's slot as it is now."""
        reasoning = sub.reasoning
        request = VerifyRequest(subplan=reasoning.now, instruction=self.pool.task.instruction, plans=reasoning.plans,
                                index=reasoning.position(self.config.subplan_ref),
                                first_agent=sub.first_agent, task=self.pool.task.key, candidate=c.slot)
        atoms = self.verifier.atoms_needed(request, self._objects)
        final = self._observe(c.slot, images=self.verifier.needs_images, atoms=atoms)
        request.scene, request.final_agent, request.final_wrist = final.scene, final.agent, final.wrist
        # What the verifier is about to judge, as it will see it (verification-case collectors listen).
        self.emit("verify_request", request=request, subplan=sub.index, round=c.round, slot=c.slot, steps=c.steps,
                  ended_by=c.ended_by or "midway")
        return request

    @property
    def _in_slot_order(self) -> bool:
        return self.selection.verifies and self.config.verify_order == "slot"

    def _next_taken(self) -> int:
        self._taken += 1
        return self._taken

    def _settle(self, cands: list[Candidate], result: SteerResult) -> None:
        """Slot order: wait for every verdict still out (those of the candidates that ended at this
        chunk boundary) and take them candidate 0 first."""
        t0 = time.perf_counter()
        for c in cands:
            if c.future is not None and c.verdict is None:
                self._take_verdict(c)
        result.timing["verify_wait_s"] += time.perf_counter() - t0

    def _take_checks(self, cands: list[Candidate], active: list[int], result: SteerResult) -> None:
        """A passed mid-rollout check ends its candidate at the checked point (the later chunks,
        already run in its slot, are dropped: the commit syncs to the checked snapshot). In slot
        order every check made at this boundary is waited for, candidate 0 first."""
        wait = self._in_slot_order
        t0 = time.perf_counter()
        for i in list(active):
            c = cands[i]
            for chk in c.checks:
                if chk.verdict is None and (wait or chk.future.done()):
                    chk.verdict = chk.future.result()
                    self._account(chk.verdict)
                if chk.verdict is not None and chk.verdict.passed:
                    c.actions, c.steps, c.snapshot = c.actions[: chk.chunks], chk.steps, chk.snapshot
                    c.verdict, c.ended_by = chk.verdict, "verified"
                    c.t_end = c.t_verified = time.perf_counter()
                    c.taken = self._next_taken()
                    active.remove(i)
                    break
        if wait:
            result.timing["verify_wait_s"] += time.perf_counter() - t0

    def _first_pass(self, cands: list[Candidate]) -> Candidate | None:
        if self.selection.verifies:  # collect the verdicts that have come in meanwhile
            for c in cands:
                if c.future is not None and c.future.done() and c.verdict is None:
                    self._take_verdict(c)
        return self.selection.early_winner(cands)

    def _wait_for_verdicts(self, cands, result) -> Candidate | None:
        if not self.selection.verifies:
            return None
        t0 = time.perf_counter()
        for c in sorted((c for c in cands if c.future is not None and c.verdict is None), key=lambda c: c.t_end):
            self._take_verdict(c)
            if c.verdict.passed and self.selection.stops_at_first_pass:
                break
        result.timing["verify_wait_s"] += time.perf_counter() - t0
        return self._first_pass(cands)

    def _take_verdict(self, c: Candidate) -> None:
        """Collect a finished verification; every call is paid for, winner or not."""
        c.verdict, c.t_verified = c.future.result(), time.perf_counter()
        c.taken = self._next_taken()
        self._account(c.verdict)

    def _account(self, verdict: Verdict) -> None:
        self._result.input_tokens += verdict.input_tokens
        self._result.output_tokens += verdict.output_tokens
        self._result.cost_usd += verdict.cost_usd

    # ---- commit ----------------------------------------------------------------------------
    def _commit(self, winner: Candidate, committed: Snapshot, result: SteerResult, reasoning) -> Snapshot:
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
        aligned, held = self._aligned(reasoning)
        result.aligned.append(aligned)
        self.emit("commit", slot=winner.slot, round=winner.round, steps=target.steps, snapshot=target.id,
                  ended_by=winner.ended_by, verdict=_verdict_dict(winner.verdict), aligned=aligned,
                  aligned_held=held)
        return target

    def _aligned(self, reasoning) -> tuple[bool | None, bool | None]:
        """The seed's reasoning-action alignment, made measurable: do the goal atoms the oracle grounds
        the sub-plan to hold in the committed state (slot 0)? An audit for every method, verified or
        not; its answer never reaches the selection. A "sub-plan" that is the whole instruction (a
        policy that writes none, like the non-reasoning twin) is not audited: that is task success.

        Two answers, from one check: a pick under robosuite's pad check (``aligned``, what every stored
        row's ``subplans_aligned`` counts, so it stays comparable) and under ``Held`` (``aligned_held``,
        the oracle's and the expert's pick check: an object carried on a finger's body is picked)."""
        if reasoning.now.strip().lower() == self.pool.task.instruction.strip().lower():
            return None, None
        g = ground(reasoning.now, tuple(reasoning.plans), self._objects, reasoning.position(self.config.subplan_ref))
        pads, held = checked_atoms(g, "pads"), checked_atoms(g, "fingers")
        if not pads:
            return None, None
        facts = self.pool.check(list(dict.fromkeys(pads + held)), slots=[0])[0]
        return all(facts[a] for a in pads), all(facts[a] for a in held)

    # ---- what a selection may call (`seal.steer.selection.Loop`) -------------------------------
    @property
    def instruction(self) -> str:
        return self.pool.task.instruction

    def begin(self, sub: Subplan, k: int) -> None:
        self.pool.sync(sub.committed)
        self.policy.begin(k)

    def sample(self, obs: list[Observation], reasoning: Reasoning, rows: list[int]) -> list[ActionChunk]:
        return self.policy.act(obs, reasoning, rows=rows)

    def scoring_view(self, obs: Observation, agent: np.ndarray | None = None) -> Observation:
        return scoring_view(self.scorer, obs, lambda images: self._observe(0, images=images, atoms=None).agent, agent)

    def score(self, obs: Observation, chunks: np.ndarray, goal: str) -> np.ndarray:
        return np.asarray(self.scorer.score(obs, chunks, goal))

    def step(self, chunk: np.ndarray):
        images = self.policy_images or (scoring_images(self.scorer) if self.scorer is not None else False)
        return self.pool.step({0: chunk}, observe=True, images=images, privileged_atoms=self.atoms,
                              stop_on_success=True)[0]

    # ---- small helpers ------------------------------------------------------------------------
    def _observe(self, slot: int, *, images: bool, atoms) -> Observation:
        return self.pool.observe([slot], images=images, privileged_atoms=atoms)[0]

    def _goal_atoms(self) -> list[str]:
        return [str(a) for a in self.pool.task.goal_atoms()]

    def emit(self, event: str, **fields) -> None:
        for subscriber in self.subscribers:
            subscriber.on_event(event, fields)


def _verdict_dict(v: Verdict | None) -> dict | None:
    if v is None:
        return None
    return {"success": v.success, "rationale": v.rationale, "latency_s": round(v.latency_s, 4),
            "score": v.score, "cached": bool(v.extra.get("cached", False)), "error": v.extra.get("error")}


def _add_worker_times(result: SteerResult, stepped) -> None:
    result.timing["physics_cpu_s"] += sum(r.physics_s for r in stepped)
    result.timing["render_cpu_s"] += sum(r.render_s for r in stepped)
