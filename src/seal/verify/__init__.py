"""Who judges: verifiers decide whether a predicted outcome matches a sub-plan.

``make_verifier`` builds one by name: ``oracle`` (simulator ground truth through lexicon
grounding), ``openai`` / ``gemini`` (a VLM looking at the views), ``noisy`` (the oracle with
injected errors). Any of them with a false-positive or false-negative rate is wrapped in
``NoisyVerifier`` to study how verifier errors move success. A learned verifier registers a
factory ``(*, model, base_url, seed, **opts) -> Verifier`` with ``VERIFIERS.register``.
"""

from __future__ import annotations

from seal.registry import Registry


def _oracle(**_):
    from seal.verify.oracle import OracleVerifier

    return OracleVerifier()


def _vlm(backend: str):
    def make(*, model: str | None = None, base_url: str | None = None, seed: int = 0, **opts):
        from seal.verify.vlm import make_vlm_verifier

        return make_vlm_verifier(backend, model=model, base_url=base_url, **opts)

    return make


VERIFIERS = Registry("verifier", {"oracle": _oracle, "openai": _vlm("openai"), "gemini": _vlm("gemini"),
                                  "noisy": _oracle})  # noisy = the oracle, wrapped below with its rates


def make_verifier(name: str, *, model: str | None = None, base_url: str | None = None,
                  false_positive: float = 0.0, false_negative: float = 0.0, seed: int = 0, **opts):
    verifier = VERIFIERS.make(name, model=model, base_url=base_url, seed=seed, **opts)
    if false_positive or false_negative:
        from seal.verify.noisy import NoisyVerifier

        verifier = NoisyVerifier(verifier, false_positive=false_positive, false_negative=false_negative, seed=seed)
    return verifier


def verifier_for(spec, *, seed: int = 0):
    """The verifier a `MethodSpec` names, or None for a method that verifies nothing."""
    if not spec.verifies:
        return None
    return make_verifier(spec.verifier, model=spec.model, base_url=spec.base_url,
                         false_positive=spec.false_positive, false_negative=spec.false_negative, seed=seed)
