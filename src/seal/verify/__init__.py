"""Who judges: verifiers decide whether a predicted outcome matches a sub-plan.

``make_verifier`` builds one by name: ``oracle`` (simulator ground truth through lexicon
grounding), ``openai`` / ``gemini`` (a VLM looking at the views), optionally wrapped in
``NoisyVerifier`` to study how verifier errors move success.
"""

from __future__ import annotations

from seal.errors import InvalidInput

VERIFIERS = ("oracle", "openai", "gemini")


def make_verifier(name: str, *, model: str | None = None, base_url: str | None = None,
                  false_positive: float = 0.0, false_negative: float = 0.0, seed: int = 0, **opts):
    if name == "oracle":
        from seal.verify.oracle import OracleVerifier

        verifier = OracleVerifier()
    elif name in ("openai", "gemini"):
        from seal.verify.vlm import make_vlm_verifier

        verifier = make_vlm_verifier(name, model=model, base_url=base_url, **opts)
    else:
        raise InvalidInput(f"unknown verifier {name!r}; valid: {', '.join(VERIFIERS)}")
    if false_positive or false_negative:
        from seal.verify.noisy import NoisyVerifier

        verifier = NoisyVerifier(verifier, false_positive=false_positive, false_negative=false_negative, seed=seed)
    return verifier
