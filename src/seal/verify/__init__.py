"""Who judges: verifiers decide whether a predicted outcome matches a sub-plan.

``make_verifier`` builds one by name: ``oracle`` (simulator ground truth through lexicon
grounding), ``openai`` / ``gemini`` (a VLM looking at the views), ``noisy`` (the oracle with
injected errors), ``learned`` (a small CNN trained by `seal train verifier`, `learned.py`; its
checkpoint directory is ``model``, or written into the name: ``learned:RUN_DIR``). Any of them with a false-positive or false-negative rate is wrapped in
``NoisyVerifier`` to study how verifier errors move success. Each entry carries its options
class (`options.py`). A new verifier registers a factory ``(*, model, base_url, seed, **opts) ->
Verifier`` with ``VERIFIERS.register(name, factory, OptionsClass)``; its options beyond the
common ones arrive as keyword arguments.
"""

from __future__ import annotations

from dataclasses import asdict

from seal.registry import Plugin, Registry
from seal.verify.options import GRASP_CHECKS, MISS_SCORES, LearnedOptions, OracleOptions, VerifierOptions


def _oracle(*, grasp: str = GRASP_CHECKS[0], miss_score: str = MISS_SCORES[0], **_):
    from seal.verify.oracle import OracleVerifier

    return OracleVerifier(grasp=grasp, miss_score=miss_score)


def _vlm(backend: str):
    def make(*, model: str | None = None, base_url: str | None = None, seed: int = 0, **opts):
        from seal.verify.vlm import make_vlm_verifier

        return make_vlm_verifier(backend, model=model, base_url=base_url, **opts)

    return make


def _learned(*, model: str | None = None, base_url: str | None = None, seed: int = 0, **opts):
    from seal.verify.learned import LearnedVerifier

    return LearnedVerifier(model, **opts)


VERIFIERS = Registry("verifier", {
    "oracle": Plugin(_oracle, OracleOptions, "simulator truth: the sub-plan's goal atoms"),
    "openai": Plugin(_vlm("openai"), VerifierOptions, "a VLM judging the views (--model, --base-url)"),
    "gemini": Plugin(_vlm("gemini"), VerifierOptions, "a Gemini VLM judging the views (--model)"),
    "noisy": Plugin(_oracle, OracleOptions,  # noisy = the oracle, wrapped below with its rates
                    "the oracle with --false-positive / --false-negative errors"),
    "learned": Plugin(_learned, LearnedOptions, "a small CNN from `seal train verifier` (learned:RUN_DIR)"),
})


def with_path() -> tuple[str, ...]:
    """Verifiers whose name may carry a checkpoint: learned:PATH."""
    return tuple(name for name in VERIFIERS.names if VERIFIERS.options(name).checkpoint)


def split_name(name: str, model: str | None = None) -> tuple[str, str | None]:
    """``"learned:RUN"`` -> ("learned", "RUN"); any other name keeps ``model``."""
    from seal.errors import InvalidInput

    base, sep, path = name.partition(":")
    if not sep:
        return name, model
    if base not in with_path() or not path:
        raise InvalidInput(f"verifier {name!r}: only {', '.join(with_path())} takes a path (learned:RUN_DIR)")
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
    return make_verifier(spec.verifier, seed=seed, **asdict(spec.verifier_options))
