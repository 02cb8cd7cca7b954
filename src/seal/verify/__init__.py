"""Who judges: verifiers decide whether a predicted outcome matches a sub-plan.

``make_verifier`` builds one by name: ``oracle`` (simulator ground truth through lexicon
grounding), ``openai`` / ``gemini`` (a VLM looking at the views), ``noisy`` (the oracle with
injected errors), ``learned`` (a small CNN trained by `seal train verifier`, `learned.py`; its
checkpoint directory is ``model``, or written into the name: ``learned:RUN_DIR``). Any of them with a false-positive or false-negative rate is wrapped in
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


def _learned(*, model: str | None = None, base_url: str | None = None, seed: int = 0, **opts):
    from seal.verify.learned import LearnedVerifier

    return LearnedVerifier(model, **opts)


VERIFIERS = Registry("verifier", {"oracle": _oracle, "openai": _vlm("openai"), "gemini": _vlm("gemini"),
                                  "noisy": _oracle,  # noisy = the oracle, wrapped below with its rates
                                  "learned": _learned})
WITH_PATH = ("learned",)  # verifiers whose name may carry a checkpoint: learned:PATH


def split_name(name: str, model: str | None = None) -> tuple[str, str | None]:
    """``"learned:RUN"`` -> ("learned", "RUN"); any other name keeps ``model``."""
    from seal.errors import InvalidInput

    base, sep, path = name.partition(":")
    if not sep:
        return name, model
    if base not in WITH_PATH or not path:
        raise InvalidInput(f"verifier {name!r}: only {', '.join(WITH_PATH)} takes a path (learned:RUN_DIR)")
    return base, path


def make_verifier(name: str, *, model: str | None = None, base_url: str | None = None,
                  false_positive: float = 0.0, false_negative: float = 0.0, seed: int = 0, **opts):
    name, model = split_name(name, model)
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
