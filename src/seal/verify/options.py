"""The settings of the built-in verifiers (registered with them in `seal.verify.VERIFIERS`).

Every verifier takes a model (a VLM's name, a learned verifier's checkpoint; the oracle none) and
error rates: any verifier with a false-positive or false-negative rate is wrapped in the noisy
one. Light by rule: nothing here loads a model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from seal.errors import InvalidInput
from seal.options import RATE, Options, option
from seal.sim.goals import GRASP_CHECKS  # re-exported: the oracle's pick check is one of these

MISS_SCORES = ("zero", "graded")  # the oracle's score for a failed sub-plan (seal.verify.oracle)


def _threshold(text: str) -> float:
    """A ``threshold=`` in a ``--methods`` item: a probability, or an error that names it."""
    try:
        value = float(text)
    except ValueError:
        value = None
    if value is None or not 0.0 <= value <= 1.0:
        raise InvalidInput(f"threshold={text!r}: the learned verifier's threshold is a probability in [0, 1] "
                           "(P(success) at or above it passes)")
    return value


@dataclass(frozen=True)
class VerifierOptions(Options):
    model: str | None = option(None, "VLM model name (openai/gemini verifiers); learned: checkpoint directory")
    false_positive: float = option(0.0, "noisy verifier: false-positive rate", type=RATE)
    false_negative: float = option(0.0, "noisy verifier: false-negative rate", type=RATE)
    base_url: str | None = option(None, "OpenAI-compatible server URL for a VLM planner or verifier (default: "
                                        "OPENAI_BASE_URL)", hash=False)


@dataclass(frozen=True)
class OracleOptions(VerifierOptions):
    """The oracle (and the noisy oracle built on it): which contact check a pick sub-plan gets."""

    # Results stored before the Held check existed ran with the pad check: they keep their hashes.
    grasp: str = option("fingers", "oracle: a pick passes when each finger touches the object (fingers) "
                                   "or only when both finger pads do (pads, robosuite's check)",
                        choices=GRASP_CHECKS, legacy="pads", strict=True)
    # Added after results existed: at its default a configuration keeps its hash.
    miss_score: str = option("zero", "oracle: what a failed candidate scores, which SEAL's fallback ranks when no "
                                     "candidate passes: zero (all misses alike, the first is committed) or graded "
                                     "(how close its end state came: hand to object, object to region, joint travel)",
                             choices=MISS_SCORES, later=True, strict=True)


@dataclass(frozen=True)
class LearnedOptions(VerifierOptions):
    """The learned verifier: ``model`` is its checkpoint directory (None: the shipped one), also
    written ``learned:RUN_DIR``; the weights, not the path, decide the verdicts."""

    checkpoint: ClassVar[str] = "model"
    # An operating point: with the VLA, a false pass costs SEAL an episode and a refusal costs a round
    # (docs/results.md, the noise sweeps), so a stricter cut than the checkpoint's 0.5 can pay.
    threshold: float | None = option(None, "learned: P(success) at or above which a verdict passes (default: "
                                           "the checkpoint's)", type=RATE, parse=_threshold,
                                     later=True, strict=True)

    def weights(self):
        from seal.verify.learned import CHECKPOINT, checkpoint_dir

        return CHECKPOINT, checkpoint_dir(self.model)
