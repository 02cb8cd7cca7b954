"""The steering loop when the verifier says no, says nothing, or cannot answer at all.

Real simulator, real pool, and for the VLM a real OpenAI-compatible HTTP server on loopback whose
answer depends on the sub-plan it is asked about and on how often it was asked: the verifier's
client (the openai SDK), retries, the background thread and the loop all run as in production.

What must hold:
- a rejected candidate is never executed, and rejections change what runs (another round);
- without a pass, the fallback runs: more rounds, then the best score, then the first candidate;
- a verifier that fails past its retries mid-episode is counted (trace, result) and the trial is
  marked when, in most of its rounds, the verifier never answered;
- a permanent error (401, or nothing listening at the URL) stops the run with the reason.
"""

from __future__ import annotations

import json
import re
import socket
import threading
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler

import pytest
from _local_http import scrub_env, send_json, serving

from seal.errors import VerifierUnavailable
from seal.eval.execute import RunOptions
from seal.eval.runner import run_eval
from seal.eval.store import ResultStore
from seal.eval.trials import MethodSpec
from seal.policies.expert.policy import FailureKnobs
from seal.sim.pool import EnvPool
from seal.sim.suites import get_task
from seal.steer.config import SteerConfig
from seal.steer.engine import Steerer
from seal.steer.run import expert_policy
from seal.steer.trace import Trace, read_trace
from seal.verify.base import Verdict
from seal.verify.vlm import VerifierCallError, make_vlm_verifier

BOOK = get_task("libero_10", 5)  # two sub-plans: "pick up the book", then "place it ..."
PICK = "pick up the book"
SUCCESS = "The book is between the fingers.\nVerification: Success"
FAILURE = "The gripper is empty.\nVerification: Failure"
STEP = re.compile(r'Step to check: "([^"]*)"')


@dataclass
class FakeVLM:
    """``answer(step, n)`` -> (HTTP status, text) for the n-th question (0-based) about ``step``."""

    answer: object
    url: str = ""
    asked: list = field(default_factory=list)  # (step, status) in arrival order
    lock: threading.Lock = field(default_factory=threading.Lock)
    release: threading.Event = field(default_factory=threading.Event)


def _handler(fake: FakeVLM):
    class Handler(BaseHTTPRequestHandler):
        def do_POST(self):  # noqa: N802 (http.server naming)
            body = json.loads(self.rfile.read(int(self.headers.get("content-length", 0))))
            prompt = body["messages"][0]["content"][0]["text"]
            step = STEP.search(prompt).group(1)
            images = [p for p in body["messages"][0]["content"] if p["type"] == "image_url"]
            assert len(images) == 3  # a request without the views would be a bug worth a failed test
            with fake.lock:
                n = sum(s == step for s, _ in fake.asked)
                status, text = fake.answer(step, n)
                fake.asked.append((step, status))
            if status == 200:
                payload = {"id": "x", "object": "chat.completion", "created": 0, "model": body["model"],
                           "choices": [{"index": 0, "message": {"role": "assistant", "content": text},
                                        "finish_reason": "stop"}],
                           "usage": {"prompt_tokens": 900, "completion_tokens": 40, "total_tokens": 940}}
            else:
                payload = {"error": {"message": f"scripted {status}", "type": "scripted", "code": status}}
            send_json(self, status, payload)  # after an early exit the loop may have hung up already

        def log_message(self, *args):
            pass

    return Handler


@pytest.fixture
def vlm(monkeypatch):
    scrub_env(monkeypatch)
    started = []

    def start(answer) -> FakeVLM:
        fake = FakeVLM(answer)
        ctx = serving(fake, _handler(fake))
        ctx.__enter__()
        started.append(ctx)
        return fake

    yield start
    for ctx in started:
        ctx.__exit__(None, None, None)


def _verifier(fake: FakeVLM, **opts):
    opts.setdefault("max_retries", 1)
    opts.setdefault("backoff_s", 0.01)
    return make_vlm_verifier("openai", model="fake-vlm", base_url=f"{fake.url}/v1", api_key="sk-local", **opts)


@pytest.fixture(scope="module")
def pool():
    with EnvPool(BOOK, k=4, workers=2) as p:
        yield p


def _steer(pool, config, verifier, tmp_path, knobs=None):
    with Trace(tmp_path / "trace.jsonl") as trace:
        result = Steerer(pool, expert_policy(BOOK, knobs or FailureKnobs.misaligned(), seed=config.seed), verifier,
                         config, trace=trace).run(0)
    return result, read_trace(tmp_path / "trace.jsonl")


def _events(trace, kind):
    return [e for e in trace if e["event"] == kind]


# ---- a VLM that says yes and no -----------------------------------------------------------------
def test_rejections_by_a_vlm_change_what_is_executed(pool, vlm, tmp_path):
    """The VLM rejects the whole first round of the pick sub-plan, then accepts: the loop must run a
    second round and execute one of its candidates (base would have executed round 0's candidate)."""
    fake = vlm(lambda step, n: (200, FAILURE if step == PICK and n < 4 else SUCCESS))
    config = SteerConfig(method="seal", k=4, rounds=2, seed=3)
    result, trace = _steer(pool, config, _verifier(fake), tmp_path)

    cands, commits = _events(trace, "candidate"), _events(trace, "commit")
    rejected = [c for c in cands if c["verdict"] and c["verdict"]["success"] is False]
    assert len(rejected) == 4 and {c["round"] for c in rejected} == {0}
    assert all(c["verdict"]["success"] is True for c in commits)  # nothing rejected was executed
    assert commits[0]["round"] == 1  # a second round, which base (and a loop that ignored "no") never runs
    assert commits[0]["snapshot"] not in {c["snapshot"] for c in rejected}
    assert result.rounds == len(commits) + 1 and result.fallbacks == 0 and result.verifier_errors == 0
    assert result.success
    assert result.input_tokens >= 900 * 5  # the four rejections and the acceptance were paid for

    # The same start without steering executes round 0's first candidate: a different first commit.
    base, base_trace = _steer(pool, SteerConfig(method="base", seed=3), None, tmp_path / "base")
    assert _events(base_trace, "commit")[0]["snapshot"] != commits[0]["snapshot"]


# ---- fallbacks ----------------------------------------------------------------------------------
class AlwaysNo:
    """Rejects every candidate, with a score when ``scores`` is set: drives every fallback."""

    name = "always-no"
    needs_images = False

    def __init__(self, scores: dict | None = None):
        self.scores = scores
        self.asked = []

    def atoms_needed(self, request, objects):
        return []

    async def verify(self, request) -> Verdict:
        self.asked.append(request.candidate)
        score = None if self.scores is None else self.scores[request.candidate]
        return Verdict(False, "no", score=score)


def test_no_pass_runs_every_round_then_the_best_score_wins(pool, tmp_path):
    scores = {0: 0.1, 1: 0.2, 2: 0.9, 3: 0.3}  # slot 2 is the best-scored in both rounds
    verifier = AlwaysNo(scores)
    result, trace = _steer(pool, SteerConfig(method="seal", k=4, rounds=3, max_steps=40), verifier, tmp_path)
    cands, (commit,) = _events(trace, "candidate"), _events(trace, "commit")
    assert {c["round"] for c in cands} == {0, 1, 2} and result.rounds == 3  # every round was sampled
    assert len(verifier.asked) == 12 and result.fallbacks == 1
    assert (commit["slot"], commit["round"]) == (2, 0)  # the best score; the earliest on a tie
    assert commit["verdict"]["score"] == 0.9 and commit["verdict"]["success"] is False


def test_no_pass_and_no_score_executes_the_first_candidate(pool, tmp_path):
    result, trace = _steer(pool, SteerConfig(method="seal", k=4, rounds=2, max_steps=40), AlwaysNo(), tmp_path)
    (commit,) = _events(trace, "commit")
    first = next(c for c in _events(trace, "candidate") if c["round"] == 0 and c["slot"] == 0)
    assert (commit["slot"], commit["round"]) == (0, 0) and commit["snapshot"] == first["snapshot"]
    assert result.rounds == 2 and result.fallbacks == 1 and result.verifier_errors == 0


# ---- a verifier that stops answering --------------------------------------------------------------
# The clean expert picks the book in under 70 steps; stopping there makes the place candidates end
# at the step limit (not at task success, which needs no verifier), so each of them is verified.
PART_OF_PLACE = 70


def test_verifier_failing_mid_episode_is_counted_and_marked(pool, vlm, tmp_path):
    """Answers the pick sub-plan, then only 503s: the episode goes on by fallback, and the errors
    are counted in the result and the trace; two rounds of three got no answer at all, so the
    trial is marked."""
    fake = vlm(lambda step, n: (200, SUCCESS) if step == PICK else (503, ""))
    config = SteerConfig(method="seal", k=4, rounds=2, seed=1, max_steps=PART_OF_PLACE)
    result, trace = _steer(pool, config, _verifier(fake), tmp_path, knobs=FailureKnobs())
    assert _events(trace, "commit")[0]["verdict"]["success"] is True  # the verifier worked at first

    place_calls = [s for s, _ in fake.asked if s != PICK]
    assert len(place_calls) == 2 * 4 * 2  # 2 rounds x 4 candidates x (first try + 1 retry)
    assert result.verifier_errors == 8 and result.fallbacks == 1 and result.verifier_unavailable
    errored = [c for c in _events(trace, "candidate") if c["verdict"] and c["verdict"]["error"]]
    assert len(errored) == 8 and all("503" in c["verdict"]["error"] for c in errored)
    end = _events(trace, "episode_end")[0]
    assert (end["verifier_errors"], end["verifier_unavailable"], end["fallbacks"]) == (8, True, 1)
    assert _events(trace, "commit")[-1]["verdict"]["success"] is None  # executed unverified, and says so


class Flaky:
    """Gives no answer (as the VLM verifier does once its retries are spent) on the calls listed."""

    name = "flaky"
    needs_images = False

    def __init__(self, failing: set[int], raises: bool = False):
        self.failing, self.raises, self.n = failing, raises, 0

    def atoms_needed(self, request, objects):
        return []

    async def verify(self, request) -> Verdict:
        self.n += 1
        if self.n in self.failing:
            if self.raises:
                raise ConnectionResetError("peer reset")
            return Verdict(None, "verifier unavailable", extra={"error": "HTTP 503"})
        return Verdict(True, "ok")


@pytest.mark.parametrize("rounds,raises,mostly", [
    ([[2]], False, False),  # one round, one of three calls unanswered: that round was verified
    ([[1, 2, 3], [], []], False, False),  # one round of three without any answer
    ([[1, 2, 3], [1, 2, 3], []], False, True),  # two of three
    ([[1, 2, 3]], True, True),  # ConnectionErrors raised by the verifier count the same
])
def test_the_mark_means_the_verifier_never_answered_in_most_rounds(rounds, raises, mostly):
    """Three verifications per round; the listed ones (1-based within the round) get no answer."""
    from seal.steer.background import BackgroundVerifier
    from seal.verify.base import VerifyRequest

    failing = {3 * r + i for r, calls in enumerate(rounds) for i in calls}
    with BackgroundVerifier(Flaky(failing, raises)) as background:
        verdicts = []
        for _ in rounds:
            background.start_round()
            verdicts += [background.submit(VerifyRequest(subplan="s", instruction="i")).result(5) for _ in range(3)]
    assert [v.success for v in verdicts] == [None if i + 1 in failing else True for i in range(len(verdicts))]
    assert (background.calls, background.errors) == (3 * len(rounds), len(failing))
    assert background.mostly_unavailable is mostly
    if raises:  # a ConnectionError raised by a verifier is transient too, with its reason kept
        assert "ConnectionResetError: peer reset" in verdicts[0].extra["error"]


def test_a_verifier_bug_is_not_an_unknown_verdict():
    from seal.steer.background import BackgroundVerifier
    from seal.verify.base import VerifyRequest

    class Broken(Flaky):
        async def verify(self, request):
            raise KeyError("no such atom")

    with BackgroundVerifier(Broken(set())) as background:
        with pytest.raises(KeyError):
            background.submit(VerifyRequest(subplan="s", instruction="i")).result(5)


def test_permanent_error_mid_episode_stops_the_run_at_once(pool, vlm, tmp_path):
    """The key is revoked after the first sub-plan: the next answer is a 401, and the episode stops
    there with the reason (no retry, no further candidate verified, no silent 'execute candidate 0')."""
    fake = vlm(lambda step, n: (200, SUCCESS) if step == PICK else (401, ""))
    with pytest.raises(VerifierCallError, match=r"HTTP 401.*API key"):
        _steer(pool, SteerConfig(method="seal", k=4, seed=1, max_steps=PART_OF_PLACE),
               _verifier(fake, max_retries=3), tmp_path, knobs=FailureKnobs())
    place = [st for s, st in fake.asked if s != PICK]
    assert place and set(place) == {401} and len(place) <= 4  # never retried: at most one call per candidate
    trace = read_trace(tmp_path / "trace.jsonl", strict=False)
    assert len(_events(trace, "commit")) == 1 and not _events(trace, "episode_end")


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]  # closed again on exit: connecting to it is refused


def test_eval_stops_on_a_wrong_key_or_a_server_that_is_down(vlm, monkeypatch, tmp_path):
    """`seal eval` with a VLM verifier that can never answer stops at its first call with the
    reason, and stores nothing for that trial (so re-running the command after the fix redoes it)."""
    fake = vlm(lambda step, n: (401, ""))
    monkeypatch.setenv("OPENAI_API_KEY", "sk-wrong")
    spec = MethodSpec(method="seal", k=2, verifier="openai", model="fake-vlm")
    options = RunOptions(out_dir=str(tmp_path / "runs"), video="none", grids=False, max_steps=60)
    for url, why in ((f"{fake.url}/v1", r"HTTP 401"), (f"http://127.0.0.1:{_closed_port()}/v1", "cannot reach")):
        monkeypatch.setenv("OPENAI_BASE_URL", url)  # what the spawned trial worker's SDK reads
        db = tmp_path / f"{why[:6]}.db"
        with pytest.raises(VerifierUnavailable, match=f"stopped the run: .*{why}.*re-run the same command"):
            run_eval(str(db), [spec], ["libero_10"], [5], 2, options=options)
        with ResultStore(db) as store:
            assert store.count() == 0
    assert 1 <= len(fake.asked) <= 2  # one call per candidate at most: not retried, no second trial started


def test_cli_run_prints_the_reason_and_fails(vlm, monkeypatch, tmp_path, capsys):
    from seal.cli import main

    monkeypatch.setenv("OPENAI_API_KEY", "sk-local")

    fake = vlm(lambda step, n: (404, ""))  # e.g. a model name the server does not know
    code = main(["run", "--suite", "libero_10", "--task", "5", "--method", "seal", "--k", "2", "--verifier", "openai",
                 "--model", "no-such-model", "--base-url", f"{fake.url}/v1", "--max-steps", "60", "--no-video",
                 "--no-grids", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and "HTTP 404" in err and "model name" in err
    assert not (tmp_path / "run" / "summary.json").exists()


def test_eval_counts_transient_errors_per_trial_and_warns(vlm, monkeypatch, tmp_path, capsys):
    """`seal eval` against a VLM that only answers 503: the trial runs on by fallback, its row counts
    the verifications that got no answer and is marked, and the command's summary and stderr say so."""
    from seal.cli import main

    fake = vlm(lambda step, n: (503, ""))
    monkeypatch.setenv("OPENAI_API_KEY", "sk-local")
    monkeypatch.setenv("OPENAI_BASE_URL", f"{fake.url}/v1")  # what the spawned trial worker's SDK reads
    db = tmp_path / "r.db"
    code = main(["eval", "--suite", "libero_10", "--tasks", "5", "--trials", "1", "--methods", "seal",
                 "--k", "2", "--rounds", "1", "--verifier", "openai", "--model", "fake-vlm", "--db", str(db),
                 "--max-steps", "25", "--video", "none", "--no-grids"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    summary = json.loads(captured.out.strip().splitlines()[-1])
    (label,) = summary["verifier_errors"]
    assert summary["verifier_errors"][label] == 2 and summary["verifier_unavailable"][label] == 1
    assert "2 verification(s) got no answer" in captured.err and "1 trial(s) mostly unverified" in captured.err
    with ResultStore(db) as store:
        (row,) = store.rows()
    assert row.status == "ok" and (row.verifier_calls, row.verifier_errors, row.verifier_unavailable) == (2, 2, True)
    assert row.fallbacks == 1 and len(fake.asked) == 2 * 4  # two candidates, each tried 4 times (3 retries)
