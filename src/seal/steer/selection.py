"""How each method picks the candidate it commits: one small object per method.

The loop (`seal.steer.engine`) runs rounds of K candidates and asks the method's selection
three questions: how many candidates and rounds, which finished candidate (if any) wins early,
and which one to fall back on when no round produced a winner. ``value`` does not run rounds of
whole candidates at all: it re-ranks K sampled chunks at every step, so it brings its own
sub-plan loop.

    base    K=1, nothing verified: the policy alone; its one candidate wins when it ends
    random  K candidates, one round; a random finished one
    seal    K candidates, verified in the background; the first that passes wins (early exit);
            "first" is the first verdict the loop took: in slot order (the default) the verdicts
            of each chunk boundary are taken candidate 0 first, in arrival order as they come in;
            no pass after ``rounds`` rounds -> the best verifier score, else the first.
            With pick="best", every candidate of the round runs and is judged, and the pass
            with the highest verifier score wins (no early exit: it spends the whole round
            to trust a confident verdict over an early one)
    value   V-GPS: at every chunk the scorer's best of K chunks is executed

A selection sees the loop only through `Loop`: whole rounds of candidates, or (value) one batched
sample, the scorer's view and score, one step of the committed slot. The methods are registered
by name in `seal.steer.config.METHODS`.
"""

from __future__ import annotations

import time
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from seal.errors import InvalidInput
from seal.policies.base import ACTION_HORIZON, ActionChunk, Reasoning
from seal.sim.observation import Observation
from seal.sim.snapshot import Snapshot
from seal.steer.result import SteerResult
from seal.verify.base import Verdict

if TYPE_CHECKING:
    from seal.sim.pool import SlotResult
    from seal.steer.background import BackgroundVerifier


@dataclass
class Candidate:
    round: int
    slot: int
    actions: list = field(default_factory=list)  # executed (5-step) chunks, in order
    steps: int = 0
    snapshot: Snapshot | None = None
    ended_by: str = ""  # think | budget | step_limit | task_success | verified | error | stopped
    error: str | None = None
    verdict: Verdict | None = None
    future: Future | None = None
    t_start: float = 0.0
    t_end: float = 0.0
    t_verified: float = 0.0
    # when the loop took its verdict, counted (1, 2, ...; 0: none): "first to pass" compares this, not clocks
    taken: int = 0
    checks: list = field(default_factory=list)  # mid-rollout checks of a policy that never thinks


@dataclass
class Check:
    """A verification of a candidate's state part-way through its rollout."""

    future: Future | None  # None until submitted (slot order submits at the chunk boundary)
    snapshot: Snapshot
    chunks: int  # executed chunks up to this point
    steps: int
    verdict: Verdict | None = None


@dataclass
class Subplan:
    """Everything the rounds of one sub-plan share (the loop's per-sub-plan state)."""

    index: int  # 1-based, in the episode
    committed: Snapshot  # where every candidate starts
    obs0: Observation  # the observation at that state (the verifier's "before" image)
    reasoning: Reasoning
    max_steps: int  # the episode's step limit
    background: "BackgroundVerifier | None"
    result: SteerResult
    tried: list[Candidate] = field(default_factory=list)
    first_agent: "np.ndarray | None" = None  # the verifier's "before" agent view (224 px; obs0's own if that is 224)


class Settings(Protocol):
    """What a selection reads of the loop's settings (`seal.steer.config.LoopSettings` and
    `SteerConfig` have these fields); a protocol, so this module does not import the config that
    names it."""

    k: int
    rounds: int
    pick: str
    value_goal: str
    subplan_budget: int


class Loop(Protocol):
    """What a selection may call on the steering loop (`seal.steer.engine.Steerer` implements it)."""

    config: Settings
    rng: np.random.Generator

    @property
    def instruction(self) -> str:
        """The task's instruction."""
        ...

    def run_round(self, sub: Subplan, r: int) -> Candidate | None:
        """K candidates from the committed state until one wins or all end; the winner or None."""
        ...

    def begin(self, sub: Subplan, k: int) -> None:
        """Every slot back to the committed state; the policy starts ``k`` attempts at the sub-plan."""
        ...

    def sample(self, obs: list[Observation], reasoning: Reasoning, rows: list[int]) -> list[ActionChunk]:
        """One batched ``act`` call: a chunk per row."""
        ...

    def scoring_view(self, obs: Observation, agent: "np.ndarray | None" = None) -> Observation:
        """What the scorer scores at the committed slot's state (``agent``: a view already rendered)."""
        ...

    def score(self, obs: Observation, chunks: np.ndarray, goal: str) -> np.ndarray:
        """The scorer's K scores, higher is better."""
        ...

    def step(self, chunk: np.ndarray) -> "SlotResult":
        """Slot 0 executes one chunk, observed as the policy and the scorer need."""
        ...

    def emit(self, event: str, **fields) -> None:
        ...


class Selection:
    """The base method: one candidate, nothing verified; subclasses change the answers."""

    name = "base"
    verifies = False  # finished candidates go to the verifier
    scores = False  # chunks are ranked by a ChunkScorer (the episode builder loads one)
    stops_at_first_pass = True  # the loop stops collecting verdicts once one passes
    # the loop settings (per_method ones, `seal.steer.config.LoopSettings`) that change this method's results:
    # only these enter its config hash
    uses: tuple[str, ...] = ()

    @classmethod
    def for_settings(cls, settings: Settings) -> "Selection":
        return cls()

    def k(self, config: Settings) -> int:
        return 1

    def rounds(self, config: Settings) -> int:
        return 1

    def check(self, verifier, scorer) -> None:
        """Refuse a loop that lacks what this method needs."""

    def judge_needs_images(self, verifier, scorer) -> bool:
        """Whether this method's judge (verifier or scorer) looks at the sub-plan's first frame."""
        return self.verifies and verifier is not None and verifier.needs_images

    def early_winner(self, cands: list[Candidate]) -> Candidate | None:
        """A winner while candidates may still be running (ends the round)."""
        first = cands[0]
        return first if first.ended_by and first.error is None else None

    def fallback(self, usable: list[Candidate], rng: np.random.Generator, result: SteerResult) -> Candidate:
        """No round produced a winner: pick among the candidates that ended cleanly."""
        scored = [c for c in usable if c.verdict is not None and c.verdict.score is not None]
        return max(scored, key=lambda c: c.verdict.score) if scored else usable[0]

    def run_subplan(self, loop: Loop, sub: Subplan) -> Candidate | None:
        """Rounds of K candidates until one wins; None when every candidate hit a simulator error."""
        for r in range(self.rounds(loop.config)):
            sub.result.rounds += 1
            winner = loop.run_round(sub, r)
            if winner is not None:
                return winner
        usable = [c for c in sub.tried if c.error is None and c.snapshot is not None]
        if not usable:
            return None
        return self.fallback(usable, loop.rng, sub.result)


class RandomSelection(Selection):
    name = "random"
    uses = ("k",)

    def k(self, config):
        return config.k

    def early_winner(self, cands):
        return None  # decided once every candidate has ended

    def fallback(self, usable, rng, result):
        return usable[int(rng.integers(len(usable)))]


class SealSelection(Selection):
    name = "seal"
    verifies = True
    uses = ("k", "rounds", "check_every", "pick", "verify_order", "done_check", "subplan_ref")

    def __init__(self, pick: str = "first"):
        self.pick = pick
        self.stops_at_first_pass = pick == "first"

    @classmethod
    def for_settings(cls, settings):
        return cls(settings.pick)

    def k(self, config):
        return config.k

    def rounds(self, config):
        return config.rounds

    def check(self, verifier, scorer):
        if verifier is None:
            raise InvalidInput("method 'seal' needs a verifier (e.g. --verifier oracle)")

    def early_winner(self, cands):
        passed = [c for c in cands if c.verdict is not None and c.verdict.passed]
        if self.pick == "first":
            return min(passed, key=lambda c: c.taken) if passed else None
        settled = all(c.error is not None or c.verdict is not None for c in cands)
        if not settled or not passed:  # a candidate still running or being judged may score higher
            return None
        return max(passed, key=lambda c: (1.0 if c.verdict.score is None else c.verdict.score, -c.taken))

    def fallback(self, usable, rng, result):
        result.fallbacks += 1
        return super().fallback(usable, rng, result)


class ValueSelection(Selection):
    """V-GPS: sample K chunks from one state, execute the one the scorer rates best, repeat."""

    name = "value"
    scores = True
    uses = ("k", "value_goal")

    def k(self, config):
        return config.k

    def check(self, verifier, scorer):
        if scorer is None:
            raise InvalidInput("method 'value' needs a chunk scorer (a trained V-GPS Q-function)")

    def judge_needs_images(self, verifier, scorer):
        return scorer is not None and bool(scorer.needs_images)

    def run_subplan(self, loop: Loop, sub: Subplan) -> Candidate | None:
        cfg, k, result, reasoning = loop.config, loop.config.k, sub.result, sub.reasoning
        goal = loop.instruction if cfg.value_goal == "task" else reasoning.now
        loop.begin(sub, k)
        c = Candidate(round=0, slot=0, snapshot=sub.committed, t_start=time.perf_counter())
        obs, judged = sub.obs0, loop.scoring_view(sub.obs0, sub.first_agent)
        while True:
            t0 = time.perf_counter()
            chunks = loop.sample([obs] * k, reasoning, list(range(k)))
            acting = [i for i, ch in enumerate(chunks) if not ch.think]
            end = ("think" if len(acting) <= k // 2 else "budget" if c.steps >= cfg.subplan_budget
                   else "step_limit" if sub.committed.steps + c.steps >= sub.max_steps else "")
            if end:  # most samples say the sub-plan is done: the policy would think now
                c.ended_by, c.t_end = end, time.perf_counter()
                break
            scores = loop.score(judged, np.stack([chunks[i].actions for i in acting]), goal)
            best = acting[int(np.argmax(scores))]
            result.timing["sampling_s"] += time.perf_counter() - t0
            t0 = time.perf_counter()
            chunk = np.clip(chunks[best].actions[:ACTION_HORIZON], -1.0, 1.0)
            res = loop.step(chunk)
            if res.ok and not res.success:
                judged = loop.scoring_view(res.observation)
            result.timing["predict_s"] += time.perf_counter() - t0
            result.timing["physics_cpu_s"] += res.physics_s
            result.timing["render_cpu_s"] += res.render_s
            if not res.ok:
                c.error, c.ended_by = res.error or "sim_error", "error"
                return None
            c.actions.append(chunk[: res.steps])
            c.steps += res.steps
            c.snapshot, obs = res.snapshot, res.observation
            if res.success:
                c.ended_by, c.t_end = "task_success", time.perf_counter()
                break
        loop.emit("candidate", round=0, slot=0, steps=c.steps, ended_by=c.ended_by, error=c.error,
                  snapshot=c.snapshot.id, verdict=None, t_start=c.t_start, t_end=c.t_end, t_verified=0.0)
        return c
