import asyncio
import random
from dataclasses import replace

import numpy as np
import pytest

from seal.errors import InvalidInput
from seal.policies.expert.policy import FailureKnobs
from seal.sim.pool import EnvPool
from seal.sim.suites import get_task
from seal.sim.world import LiberoWorld, PhysicsMismatch
from seal.steer.config import SteerConfig
from seal.steer.engine import Steerer
from seal.steer.run import expert_policy
from seal.steer.trace import TIMING_FIELDS, Trace, read_trace, same_episode, without_timing
from seal.verify.base import Verdict
from seal.verify.oracle import OracleVerifier

BOOK = get_task("libero_10", 5)  # two sub-plans, ~90 steps: the quickest LIBERO-10 task


class SlowOracle(OracleVerifier):
    """The oracle answering after a fixed delay, like a VLM call."""

    def __init__(self, delay: float):
        self.delay = delay

    async def verify(self, request) -> Verdict:
        await asyncio.sleep(self.delay)
        return await super().verify(request)


@pytest.fixture(scope="module")
def pool():
    with EnvPool(BOOK, k=4, workers=2) as p:
        yield p


def _steer(pool, config, verifier, knobs, tmp_path, **kw):
    with Trace(tmp_path / "trace.jsonl") as trace:
        result = Steerer(pool, expert_policy(BOOK, knobs, seed=config.seed), verifier, config, trace=trace,
                         **kw).run(0)
    return result, read_trace(tmp_path / "trace.jsonl")


def test_seal_episode_commits_verified_winners(pool, tmp_path):
    result, trace = _steer(pool, SteerConfig(method="seal", k=4), OracleVerifier(), FailureKnobs.misaligned(), tmp_path)
    assert result.success and not result.sim_error
    events = [e["event"] for e in trace]
    assert events[0] == "subplan" and events[-1] == "episode_end" and events.count("commit") >= 2
    commits = [e for e in trace if e["event"] == "commit"]
    assert all(c["verdict"]["success"] for c in commits)  # nothing unverified was executed
    assert commits[-1]["steps"] == result.steps == len(result.executed_actions)
    assert result.ended_by == trace[-1]["ended_by"] == "goal_holds"
    cands = [e for e in trace if e["event"] == "candidate"]
    assert {c["ended_by"] for c in cands} <= {"think", "budget", "step_limit", "task_success", "stopped", "error"}
    assert result.verifier_calls >= 2


class SlotScoredOracle(OracleVerifier):
    """The oracle's verdicts with a score that grows with the slot: pick=best must commit the
    highest passing slot of its round, pick=first the first to pass."""

    async def verify(self, request) -> Verdict:
        verdict = await super().verify(request)
        return replace(verdict, score=0.5 + 0.1 * request.candidate) if verdict.success else verdict


def test_best_pick_judges_the_whole_round_and_commits_its_most_confident_pass(pool, tmp_path):
    config = SteerConfig(method="seal", k=4, pick="best")
    result, trace = _steer(pool, config, SlotScoredOracle(), FailureKnobs.misaligned(), tmp_path)
    assert result.success and not result.sim_error
    rounds, current = [], []
    for e in trace:
        if e["event"] == "candidate":
            current.append(e)
        elif e["event"] == "commit":
            rounds.append((e, current))
            current = []
        elif e["event"] == "round_end":
            current = []
    assert rounds
    for commit, cands in rounds:
        if commit["ended_by"] == "task_success":
            continue  # the task's own check decided it
        assert all(c["verdict"] is not None for c in cands if c["error"] is None)  # nobody stopped early
        passed = [c["slot"] for c in cands if c["verdict"] and c["verdict"]["success"]]
        if passed:
            assert commit["slot"] == max(passed), (commit, passed)
    with pytest.raises(InvalidInput, match="pick"):
        SteerConfig(method="seal", pick="last")


def test_base_method_runs_one_unverified_candidate(pool, tmp_path):
    result, trace = _steer(pool, SteerConfig(method="base", k=4), None, FailureKnobs(), tmp_path)
    assert result.success and result.verifier_calls == 0
    assert {e["slot"] for e in trace if e["event"] == "candidate"} == {0}


def test_background_verification_overlaps_sampling_and_exits_early(pool, tmp_path):
    # the pick sub-plan only; in arrival order (slot order waits for each boundary's verdicts)
    config = SteerConfig(method="seal", k=4, seed=1, max_steps=60, verify_order="arrival")
    result, trace = _steer(pool, config, SlowOracle(2.0), FailureKnobs.misaligned(), tmp_path)
    first_round = [e for e in trace if e["event"] == "candidate" and e["round"] == 0][:4]
    verified = [c for c in first_round if c["verdict"] is not None]
    assert verified
    first = min(verified, key=lambda c: c["t_end"])
    # sampling of the other candidates went on while the first verification was in flight
    assert any(c["steps"] > first["steps"] for c in first_round)
    # early exit: the round's verification wall time is well under K sequential calls
    span = max(c["t_verified"] for c in verified) - first["t_end"]
    assert span < 3 * 2.0


class DelayedOracle(OracleVerifier):
    """The oracle answering after a delay per call: a random one drawn from ``seed`` (verdicts then
    come in in an order unrelated to the candidates'), plus ``hold`` seconds for the slots in ``held``."""

    def __init__(self, seed: int | None = None, most: float = 0.3, held=(), hold: float = 1.0):
        self.rng, self.most, self.held, self.hold = random.Random(seed), most if seed is not None else 0.0, held, hold

    async def verify(self, request) -> Verdict:
        delay = self.rng.uniform(0.0, self.most) + (self.hold if request.candidate in self.held else 0.0)
        await asyncio.sleep(delay)
        return await super().verify(request)


def test_slot_order_gives_the_same_trace_whatever_order_verdicts_arrive_in(pool, tmp_path):
    """verify_order="slot" (the default): an episode is a function of its seeds. Verdicts delayed at
    random, or the winner's held back, leave the trace as it was but for its clock readings; in
    arrival order the same hold hands the round to another candidate."""
    config = SteerConfig(method="seal", k=4, seed=1, max_steps=60)  # the pick sub-plan, then part of the place
    knobs = FailureKnobs.misaligned()
    _, reference = _steer(pool, config, OracleVerifier(), knobs, tmp_path / "plain")
    first = next(i for i, e in enumerate(reference) if e["event"] == "commit")
    winner = reference[first]
    together = [e["slot"] for e in reference[:first] if e["event"] == "candidate" and e["steps"] == winner["steps"]
                and e["verdict"] and e["verdict"]["success"]]
    # several candidates passed at the winner's chunk boundary: which verdict comes first is up to timing
    assert len(together) >= 2 and winner["slot"] == min(together), (winner, together)
    for name, verifier in (("shuffled", DelayedOracle(seed=7)), ("held", DelayedOracle(held={winner["slot"]}))):
        _steer(pool, config, verifier, knobs, tmp_path / name)
        assert same_episode(tmp_path / name / "trace.jsonl", tmp_path / "plain" / "trace.jsonl"), name
    # what the helper dropped: clock readings only
    plain = (tmp_path / "plain" / "trace.jsonl").read_text()
    assert '"t_verified"' in plain and '"latency_s"' in plain
    stripped = without_timing(reference)
    assert all(not TIMING_FIELDS & {*e, *(e.get("verdict") or {})} for e in stripped)
    assert [e["event"] for e in stripped] == [e["event"] for e in reference]

    _, arrival = _steer(pool, replace(config, verify_order="arrival"), DelayedOracle(held={winner["slot"]}), knobs,
                        tmp_path / "arrival")
    commit = next(e for e in arrival if e["event"] == "commit")
    assert commit["slot"] in together and commit["slot"] != winner["slot"]
    assert without_timing(arrival) != without_timing(reference)


class Batching:
    """Judges the requests that arrive together in one batch, as the learned verifier does."""

    name = "batching"
    needs_images = False

    def __init__(self):
        self.batches, self._queue = [], []

    def atoms_needed(self, request, objects):
        return []

    async def verify(self, request) -> Verdict:
        future = asyncio.get_running_loop().create_future()
        self._queue.append((request, future))
        if len(self._queue) == 1:
            asyncio.get_running_loop().call_soon(self._flush)
        return await future

    def _flush(self):
        batch, self._queue = self._queue, []
        self.batches.append([r.candidate for r, _ in batch])
        for r, f in batch:
            f.set_result(Verdict(True, f"batch of {len(batch)}", score=float(len(batch))))


def test_a_boundary_is_judged_as_one_batch_whatever_the_timing():
    """Slot order sends a chunk boundary's requests together: a batching verifier's batches (and so its
    scores' last bits) do not depend on when the verifier thread runs. One at a time, they do."""
    import time

    from seal.steer.background import BackgroundVerifier
    from seal.verify.base import VerifyRequest

    requests = [VerifyRequest(subplan="pick up the book", instruction="", candidate=i) for i in range(4)]
    verifier = Batching()
    with BackgroundVerifier(verifier) as background:
        for delay in (0.0, 0.01, 0.05):
            futures = background.submit_together(requests)
            time.sleep(delay)
            assert [f.result(timeout=5).score for f in futures] == [4.0] * 4
        # Back to back, as the engine submits boundaries: the gated version this replaced put
        # about 1 batch in 200 out of order here (the threads' race is rare, so try many).
        for _ in range(500):
            [f.result(timeout=5) for f in background.submit_together(requests)]
        assert verifier.batches == [[0, 1, 2, 3]] * 503
        verifier.batches.clear()
        for r in requests:  # arrival order: each request starts when it is submitted
            background.submit(r)
            time.sleep(0.05)
        time.sleep(0.05)
        assert len(verifier.batches) > 1


def test_replay_mode_measures_model_mismatch(tmp_path):
    exact, _ = _replay(tmp_path / "exact", None)
    assert exact.divergence and max(exact.divergence) == 0.0  # a perfect world model
    off, _ = _replay(tmp_path / "off", PhysicsMismatch(friction=0.5, mass=1.5, damping=2.0))
    assert max(off.divergence) > 1e-4


def _replay(tmp_path, mismatch):
    world = LiberoWorld(BOOK)
    try:
        with EnvPool(BOOK, k=2, workers=1, physics=mismatch) as pool:
            config = SteerConfig(method="seal", k=2, mode="replay", max_steps=60)
            return _steer(pool, config, OracleVerifier(), FailureKnobs(), tmp_path, eval_world=world)
    finally:
        world.close()


def test_bad_steering_config():
    with pytest.raises(InvalidInput, match="valid: base, random, value, seal"):
        SteerConfig(method="vgps")
    with pytest.raises(InvalidInput, match="valid: task, subplan"):
        SteerConfig(value_goal="scene")
    with pytest.raises(InvalidInput, match="valid: sync, replay"):
        SteerConfig(mode="dream")
    with pytest.raises(InvalidInput, match="valid: slot, arrival"):
        SteerConfig(verify_order="random")
    with pytest.raises(InvalidInput, match="k >= 1"):
        SteerConfig(k=0)
    with pytest.raises(InvalidInput, match="in \\[0.1, 10\\]"):
        PhysicsMismatch(friction=0.0)


class ConsensusScorer:
    """A real (if naive) scorer: prefers the chunk closest to the mean of the K samples (a consensus
    vote; the misaligned expert's action noise makes every sample, and so every score, different).
    Exercises the V-GPS path."""

    needs_images = False

    def __init__(self):
        self.calls = []
        self.scored = []  # (chunks, scores) per call, to check which one was executed

    def score(self, obs, chunks, goal):
        self.calls.append((chunks.shape, goal))
        scores = -np.linalg.norm((chunks - chunks.mean(axis=0)).reshape(len(chunks), -1), axis=1)
        self.scored.append((chunks.copy(), scores))
        return scores


def test_value_method_executes_the_best_scored_chunk_each_step(pool, tmp_path):
    scorer = ConsensusScorer()
    config = SteerConfig(method="value", k=4, max_steps=30, value_goal="subplan")
    with Trace(tmp_path / "t.jsonl") as trace:
        result = Steerer(pool, expert_policy(BOOK, FailureKnobs.misaligned(), seed=2), None, config,
                         trace=trace, scorer=scorer).run(0)
    assert scorer.calls and all(shape[0] >= 3 and shape[1:] == (16, 7) for shape, _ in scorer.calls)
    assert {goal for _, goal in scorer.calls} == {"pick up the book"}
    assert result.steps == len(result.executed_actions) == 30
    # Which chunk ran: at each call the executed 5 actions are the best-scored chunk's first five
    # (clipped as the engine clips them), and never those of a worse-scored chunk that differs.
    executed = np.asarray(result.executed_actions)
    assert len(scorer.scored) == 6  # 30 steps = 6 executed chunks of 5
    for i, (chunks, scores) in enumerate(scorer.scored):
        ran = executed[5 * i: 5 * i + 5]
        best = np.clip(chunks[int(np.argmax(scores))][:5], -1.0, 1.0)
        np.testing.assert_array_equal(ran, best)
        assert scores.max() > scores.min()  # the sampled chunks differ in score: the choice matters
        worse = [np.clip(c[:5], -1.0, 1.0) for c, sc in zip(chunks, scores) if sc < scores.max()]
        assert all(not np.array_equal(ran, w) for w in worse)
    with pytest.raises(InvalidInput, match="needs a chunk scorer"):
        Steerer(pool, expert_policy(BOOK, FailureKnobs()), None, SteerConfig(method="value", k=4))


def test_random_method_picks_one_finished_candidate_unverified(pool, tmp_path):
    config = SteerConfig(method="random", k=4, max_steps=60, seed=5)
    result, trace = _steer(pool, config, None, FailureKnobs.misaligned(), tmp_path)
    assert result.verifier_calls == 0 and result.fallbacks == 0
    commits = [e for e in trace if e["event"] == "commit"]
    assert commits and all(c["verdict"] is None for c in commits)
    first_round = [e for e in trace if e["event"] == "candidate"][:4]
    assert commits[0]["slot"] in {c["slot"] for c in first_round if c["ended_by"] != "error"}


SOUP = get_task("libero_10", 0)
SOUP_PLANS = ("pick up the alphabet soup", "place it in the basket", "pick up the tomato sauce", "place it in the basket")


class SkipsAhead:
    """The scripted expert, but its reasoning says three sub-plans are done (a learned VLA wrote this in
    evaluation): the second "place it in the basket" is the one to do now."""

    def __init__(self, expert):
        self.expert = expert
        self.thinks = expert.thinks

    def __getattr__(self, name):
        return getattr(self.expert, name)

    def reason(self, obs):
        from seal.policies.base import Reasoning

        self.own = self.expert.reason(obs)
        return Reasoning(plans=SOUP_PLANS, done=SOUP_PLANS[:3], now=SOUP_PLANS[3])

    def act(self, obs_batch, reasoning, rows=None):  # the expert acts on its own sub-plan
        return self.expert.act(obs_batch, self.own, rows)


class Requests:
    def __init__(self):
        self.seen = []

    def on_event(self, event, fields):
        if event == "verify_request":
            self.seen.append(fields["request"])


def test_a_repeated_subplan_is_judged_where_the_policy_stands_in_its_plan(tmp_path):
    """Two "place it in the basket" in one plan: after three done items, "it" is the tomato sauce
    (not the soup of the first one), for the verifier and for the alignment audit alike."""
    from seal.policies.base import Reasoning

    assert Reasoning(plans=SOUP_PLANS, done=SOUP_PLANS[:3], now=SOUP_PLANS[3]).index == 3
    assert Reasoning(plans=SOUP_PLANS, done=SOUP_PLANS[:1], now=SOUP_PLANS[1]).index == 1
    assert Reasoning(plans=SOUP_PLANS, done=(), now="open the drawer").index is None
    # a done list that also claims a later sub-plan (the VLA on the moka pots): the repeated text is the one
    # after the latest done item it follows, not the one the count of done items lands on
    moka = ("pick up the first moka pot", "place it on the stove", "pick up the second moka pot",
            "place it on the stove", "turn on the stove")
    garbled = Reasoning(plans=moka, done=(moka[0], moka[4]), now=moka[1])
    assert garbled.index == 1 and garbled.position("count") == 3
    assert Reasoning(plans=moka, done=moka[:3] + moka[4:], now=moka[3]).index == 3
    with pytest.raises(InvalidInput, match="valid: after_done, count"):
        garbled.position("last")
    requests = Requests()
    with EnvPool(SOUP, k=2, workers=1) as pool:
        result = Steerer(pool, SkipsAhead(expert_policy(SOUP, FailureKnobs(), seed=0)), OracleVerifier(),
                SteerConfig(method="seal", k=2, rounds=1, subplan_budget=10, max_steps=10),
                subscribers=(requests,)).run(0)
    assert requests.seen and all(r.index == 3 for r in requests.seen)
    assert result.ended_by == "step_limit"
    verdict = asyncio.run(OracleVerifier().verify(requests.seen[0]))
    assert "tomato_sauce_1" in verdict.rationale and not verdict.success


class DeclaresDoneEarly:
    """The scripted expert, but after its first sub-plan it writes that the task is complete (the
    learned VLA does this: a hallucinated completion). ``at_once``: it claims completion in its
    very first reasoning, with nothing done (the VLA writes that too), then reasons as the expert."""

    def __init__(self, expert, at_once: bool = False):
        self.expert, self.thinks, self.calls, self.at_once = expert, expert.thinks, 0, at_once

    def __getattr__(self, name):
        return getattr(self.expert, name)

    def reason(self, obs):
        from seal.policies.base import Reasoning

        self.calls += 1
        own = self.expert.reason(obs)
        if self.at_once:
            return Reasoning(plans=own.plans, done=(), now="") if self.calls == 1 else own
        return own if self.calls == 1 else Reasoning(plans=own.plans, done=own.plans, now="")


def test_an_episode_says_why_it_ended(pool, tmp_path):
    policy = DeclaresDoneEarly(expert_policy(BOOK, FailureKnobs(), seed=0))
    with Trace(tmp_path / "trace.jsonl") as trace:
        result = Steerer(pool, policy, None, SteerConfig(method="base", k=4), trace=trace).run(0)
    end = read_trace(tmp_path / "trace.jsonl")[-1]
    assert not result.success and result.ended_by == end["ended_by"] == "policy_finished"
    assert "Now I need to do: the task is complete." in end["reasoning"] == result.last_reasoning
    assert 0 < result.steps < BOOK.max_steps


class AlwaysPasses(OracleVerifier):
    """Says yes to everything: a verifier that cannot tell a false completion."""

    async def verify(self, request) -> Verdict:
        return Verdict(True, "looks done")


def test_a_declared_completion_is_verified(pool, tmp_path):
    """SEAL asks the verifier whether the instruction holds when the policy says the task is done:
    the oracle refuses (the book is not on the shelf yet) and the policy goes back to its last
    claimed sub-plan; a verifier that agrees, or done_check="trust", ends the episode there."""
    from seal.collect import CaseRecorder, ImagesOracle

    config = SteerConfig(method="seal", k=2, rounds=1, subplan_budget=60, max_steps=200, done_check="verify")
    recorder = CaseRecorder({"task": BOOK.key, "init_source": "official", "init_index": 0, "episode": 0})
    with Trace(tmp_path / "verify.jsonl") as trace:
        result = Steerer(pool, DeclaresDoneEarly(expert_policy(BOOK, FailureKnobs(), seed=0)), ImagesOracle(),
                         config, trace=trace, subscribers=(recorder,)).run(0)
    # a case collector keeps the task-level question as a case of kind "task", labelled by the goal
    task_cases = [r for r in recorder.rows if r["ended_by"] == "done_check"]
    assert task_cases and task_cases[0]["kind"] == "task" and task_cases[0]["label"] is False
    assert task_cases[0]["subplan"] == BOOK.instruction
    checks = [e for e in read_trace(tmp_path / "verify.jsonl") if e["event"] == "done_check"]
    assert result.done_checks and result.done_checks[0] is False and checks[0]["refused"] is True
    assert checks[0]["back_to"] == result.subplans[-1]  # the last sub-plan it claimed done, undone
    assert "is false" in checks[0]["verdict"]["rationale"]  # the task's goal atoms, checked by the oracle
    assert result.ended_by != "policy_finished"
    # taken back to its last sub-plan, the expert finishes the task the false completion left undone
    assert result.success and result.ended_by == "goal_holds"

    # completion claimed with nothing done: refused too, and the policy starts at its first sub-plan
    with Trace(tmp_path / "at_once.jsonl") as trace:
        result = Steerer(pool, DeclaresDoneEarly(expert_policy(BOOK, FailureKnobs(), seed=0), at_once=True),
                         OracleVerifier(), config, trace=trace).run(0)
    checks = [e for e in read_trace(tmp_path / "at_once.jsonl") if e["event"] == "done_check"]
    assert result.done_checks[0] is False and checks[0]["step"] == 0 and checks[0]["back_to"] == result.subplans[0]
    assert result.success and result.ended_by == "goal_holds"

    for verifier, done_check, checks_made in ((AlwaysPasses(), "verify", [True]), (OracleVerifier(), "trust", [])):
        result = Steerer(pool, DeclaresDoneEarly(expert_policy(BOOK, FailureKnobs(), seed=0)), verifier,
                         replace(config, done_check=done_check)).run(0)
        assert result.ended_by == "policy_finished" and not result.success and result.done_checks == checks_made


def test_the_repeated_subplan_audit_counts_where_the_rules_disagree(tmp_path):
    """scripts/repeated_subplans.py on two hand-written traces: one sub-plan placed differently by the two
    rules, one the same; an unknown configuration is an error that lists the ones there."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from seal.policies.base import Reasoning

    moka = ("pick up the first moka pot", "place it on the stove", "pick up the second moka pot",
            "place it on the stove", "turn on the stove")
    events = [Reasoning(moka, (moka[0], moka[4]), moka[1]), Reasoning(moka, moka[:3], moka[3])]
    for trial, r in enumerate(events):
        d = tmp_path / "libero_10" / "8" / "seal-abc" / f"trial{trial:03d}"
        d.mkdir(parents=True)
        (d / "trace.jsonl").write_text(json.dumps({"event": "subplan", "step": 5, "text": r.now,
                                                   "reasoning": r.text()}) + "\n")
    script = Path(__file__).resolve().parents[1] / "scripts" / "repeated_subplans.py"
    run = subprocess.run([sys.executable, str(script), str(tmp_path), "--configs", "seal-abc"],
                         capture_output=True, text=True, check=True)
    got = json.loads(run.stdout)["seal-abc"]
    assert (got["subplans"], got["disagree"], got["by_task"]) == (2, 1, {"8": 1})
    assert (got["example"]["after_done"], got["example"]["count"]) == (1, 3)
    bad = subprocess.run([sys.executable, str(script), str(tmp_path), "--configs", "seal-xyz"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "configurations there: seal-abc" in bad.stderr
