"""NoisyVerifier: seeded, documented verdict flips around any inner verifier."""

from __future__ import annotations

import asyncio
import math

import pytest

from seal.errors import InvalidInput
from seal.verify.base import Verdict, VerifyRequest
from seal.verify.noisy import NoisyVerifier


class Fixed:
    """An inner verifier whose answer is chosen by the candidate index."""

    name = "fixed"
    needs_images = False

    def __init__(self, answer=lambda candidate: candidate % 2 == 0):
        self.answer = answer
        self.calls = 0

    def atoms_needed(self, request, objects):
        return ["on(a,b)"]

    async def verify(self, request: VerifyRequest) -> Verdict:
        self.calls += 1
        await asyncio.sleep(0)
        return Verdict(success=self.answer(request.candidate), rationale="inner says so", score=0.9)


def _requests(n: int, subplan="pick up the bowl") -> list[VerifyRequest]:
    return [VerifyRequest(subplan=subplan, instruction="i", task="t/0", candidate=i) for i in range(n)]


def _run_all(verifier, requests) -> list[Verdict]:
    async def go():
        return [await verifier.verify(r) for r in requests]

    return asyncio.run(go())


def test_zero_rates_change_nothing():
    inner = Fixed()
    noisy = NoisyVerifier(inner, false_positive=0.0, false_negative=0.0, seed=1)
    reqs = _requests(200)
    got = _run_all(noisy, reqs)
    want = _run_all(Fixed(), reqs)
    assert [v.success for v in got] == [v.success for v in want]
    assert all(v.rationale == "inner says so" and not v.extra["noisy_flipped"] for v in got)
    assert noisy.needs_images is False and noisy.atoms_needed(reqs[0], []) == ["on(a,b)"]
    assert noisy.name.startswith("noisy(fixed")


def test_rate_one_always_flips():
    noisy = NoisyVerifier(Fixed(), false_positive=1.0, false_negative=1.0, seed=7)
    reqs = _requests(100)
    for req, verdict in zip(reqs, _run_all(noisy, reqs)):
        inner = req.candidate % 2 == 0
        assert verdict.success is (not inner)
        assert verdict.extra == {"noisy_flipped": True, "inner_success": inner}
        assert verdict.rationale.startswith("[noisy verifier: flipped")
        assert verdict.rationale.endswith("inner says so")
        assert verdict.score == pytest.approx(0.1)


def test_only_the_matching_direction_flips():
    # false positives only: successes stay, every failure becomes success
    fp = _run_all(NoisyVerifier(Fixed(), 1.0, 0.0, seed=0), _requests(50))
    assert all(v.success for v in fp)
    # false negatives only: failures stay, every success becomes failure
    fn = _run_all(NoisyVerifier(Fixed(), 0.0, 1.0, seed=0), _requests(50))
    assert not any(v.success for v in fn)


def test_unknown_stays_unknown():
    noisy = NoisyVerifier(Fixed(lambda c: None), 1.0, 1.0, seed=0)
    assert all(v.success is None for v in _run_all(noisy, _requests(20)))


def test_seeded_reproducibility_and_rates():
    reqs = _requests(2000)
    a = [v.success for v in _run_all(NoisyVerifier(Fixed(), 0.3, 0.1, seed=42), reqs)]
    b = [v.success for v in _run_all(NoisyVerifier(Fixed(), 0.3, 0.1, seed=42), reqs)]
    c = [v.success for v in _run_all(NoisyVerifier(Fixed(), 0.3, 0.1, seed=43), reqs)]
    assert a == b and a != c
    truth = [r.candidate % 2 == 0 for r in reqs]
    fp = sum(1 for s, t in zip(a, truth) if s and not t) / truth.count(False)
    fn = sum(1 for s, t in zip(a, truth) if not s and t) / truth.count(True)
    assert fp == pytest.approx(0.3, abs=0.05) and fn == pytest.approx(0.1, abs=0.04)


def test_draws_do_not_depend_on_interleaving_and_repeats_redraw():
    reqs = _requests(40)
    in_order = _run_all(NoisyVerifier(Fixed(), 0.5, 0.5, seed=3), reqs)
    shuffled_order = reqs[::-1]
    reversed_run = _run_all(NoisyVerifier(Fixed(), 0.5, 0.5, seed=3), shuffled_order)[::-1]
    assert [v.success for v in in_order] == [v.success for v in reversed_run]

    # Concurrent verification: same outcomes as sequential.
    noisy = NoisyVerifier(Fixed(), 0.5, 0.5, seed=3)

    async def concurrently():
        return await asyncio.gather(*(noisy.verify(r) for r in reqs))

    assert [v.success for v in asyncio.run(concurrently())] == [v.success for v in in_order]

    # The same question asked again gets a fresh (but still seeded) draw.
    noisy = NoisyVerifier(Fixed(), 0.5, 0.5, seed=3)
    draws = [noisy.draw(reqs[0]) for _ in range(5)]
    assert len(set(draws)) == 5 and all(0.0 <= d < 1.0 for d in draws)


@pytest.mark.parametrize("bad", [-0.01, 1.01, math.nan, math.inf, "0.1", None, True])
def test_bad_rates_rejected(bad):
    with pytest.raises(InvalidInput, match="false_positive"):
        NoisyVerifier(Fixed(), false_positive=bad, false_negative=0.0, seed=0)
    with pytest.raises(InvalidInput, match="false_negative"):
        NoisyVerifier(Fixed(), false_positive=0.0, false_negative=bad, seed=0)


def test_bad_seed_rejected():
    with pytest.raises(InvalidInput, match="seed"):
        NoisyVerifier(Fixed(), 0.1, 0.1, seed="x")
