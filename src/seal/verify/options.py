"""The settings of the built-in verifiers (registered with them in `seal.verify.VERIFIERS`).

Every verifier takes a model (a VLM's name, a learned verifier's checkpoint; the oracle none) and
error rates: any verifier with a false-positive or false-negative rate is wrapped in the noisy
one. Light by rule: nothing here loads a model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from seal.options import RATE, Options, option


@dataclass(frozen=True)
class VerifierOptions(Options):
    model: str | None = option(None, "VLM model name (openai/gemini verifiers); learned: checkpoint directory")
    false_positive: float = option(0.0, "noisy verifier: false-positive rate", type=RATE)
    false_negative: float = option(0.0, "noisy verifier: false-negative rate", type=RATE)
    base_url: str | None = option(None, "OpenAI-compatible server URL for a VLM planner or verifier (default: "
                                        "OPENAI_BASE_URL)", hash=False)


@dataclass(frozen=True)
class LearnedOptions(VerifierOptions):
    """The learned verifier: ``model`` is its checkpoint directory (None: the shipped one), also
    written ``learned:RUN_DIR``; the weights, not the path, decide the verdicts."""

    checkpoint: ClassVar[str] = "model"

    def weights(self):
        from seal.verify.learned import CHECKPOINT, checkpoint_dir

        return CHECKPOINT, checkpoint_dir(self.model)
