"""A verifier with known error rates: wraps any verifier and flips its verdicts on purpose.

Used to measure how steering degrades as the verifier gets worse (e.g. oracle + 20% false
positives) without paying for a real VLM.

Determinism: each request's random draw is a pure function of
``sha256(seed, task, subplan, candidate, n)``, where ``n`` counts how many times this same
(task, subplan, candidate) has been seen by this wrapper before. So the outcome depends on
the seed and on the requests, not on the order in which concurrent verifications finish or
on other requests interleaved between them; asking the very same question twice gives two
independent draws (n = 0, 1), as a real noisy judge would.
"""

from __future__ import annotations

import hashlib
import math
from collections import Counter
from dataclasses import replace

from seal.errors import InvalidInput
from seal.verify.base import Verdict, Verifier, VerifyRequest


def _check_rate(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InvalidInput(f"{name} must be a number in [0, 1], got {value!r}")
    if math.isnan(value) or not 0.0 <= value <= 1.0:
        raise InvalidInput(f"{name} must be in [0, 1], got {value!r}")
    return float(value)


class NoisyVerifier:
    """Flips a failure to success with prob ``false_positive`` and a success to failure with
    prob ``false_negative``; unknown verdicts pass through untouched."""

    def __init__(self, inner: Verifier, false_positive: float, false_negative: float, seed: int):
        self.inner = inner
        self.false_positive = _check_rate("false_positive", false_positive)
        self.false_negative = _check_rate("false_negative", false_negative)
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise InvalidInput(f"seed must be an int, got {seed!r}")
        self.seed = seed
        self.name = f"noisy({inner.name},fp={self.false_positive:g},fn={self.false_negative:g})"
        self.needs_images = inner.needs_images
        self._seen: Counter = Counter()

    def atoms_needed(self, request: VerifyRequest, objects: list[str]) -> list[str]:
        return self.inner.atoms_needed(request, objects)

    def draw(self, request: VerifyRequest) -> float:
        """The uniform [0, 1) number for this request; advances the per-request counter."""
        ident = (request.task, request.subplan, request.candidate)
        n = self._seen[ident]
        self._seen[ident] += 1
        text = f"{self.seed}\x00{request.task}\x00{request.subplan}\x00{request.candidate}\x00{n}"
        digest = hashlib.sha256(text.encode()).digest()
        return int.from_bytes(digest[:8], "big") / 2**64

    async def verify(self, request: VerifyRequest) -> Verdict:
        # Draw before awaiting, so the counter follows the order of calls, not of completions.
        u = self.draw(request)
        verdict = await self.inner.verify(request)
        if verdict.success is None:
            return verdict
        rate = self.false_negative if verdict.success else self.false_positive
        flipped = u < rate  # u is in [0, 1): rate 0 never flips, rate 1 always does
        extra = {**verdict.extra, "noisy_flipped": flipped, "inner_success": verdict.success}
        if not flipped:
            return replace(verdict, extra=extra)
        was, now = ("success", "failure") if verdict.success else ("failure", "success")
        kind = "false negative" if verdict.success else "false positive"
        note = f"[noisy verifier: flipped {was} -> {now}, injected {kind} at rate {rate:g}]"
        return replace(
            verdict,
            success=not verdict.success,
            rationale=f"{note} {verdict.rationale}".strip(),
            score=None if verdict.score is None else 1.0 - verdict.score,
            extra=extra,
        )
