"""The verifier seam: one async call from a predicted outcome to a verdict.

Verifiers run in the background while other candidates are still being sampled, hence
``async``. A verdict may be ``unknown`` (``success is None``): the verifier could not tell
(an ungroundable sub-plan, an unparseable answer). The steering loop treats unknown as
"not a pass" but keeps it apart from a real failure in traces and reports.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from seal.sim.scene import SceneState


@dataclass
class VerifyRequest:
    subplan: str  # the sub-plan text being judged, e.g. "pick up the alphabet soup"
    instruction: str  # the task instruction, for context
    plans: tuple[str, ...] = ()  # the whole plan, so "place it ..." can be resolved
    index: int | None = None  # position of ``subplan`` in ``plans``
    first_agent: np.ndarray | None = None  # agent view when the sub-plan started (224x224x3)
    final_agent: np.ndarray | None = None  # agent view of the candidate's predicted end state
    final_wrist: np.ndarray | None = None  # wrist view of that end state
    scene: SceneState | None = None  # privileged end state (only the oracle reads it)
    task: str = ""  # e.g. "libero_10/0"
    candidate: int = 0
    # A task-level question ("does the instruction hold?", asked when the policy says it is done):
    # ``subplan`` is then the instruction, ``first_agent`` the episode's first view, and these are the
    # task's goal atoms (the oracle checks them; a model that reads images judges the instruction text).
    goal_atoms: tuple[str, ...] = ()

    @property
    def task_level(self) -> bool:
        return bool(self.goal_atoms)


@dataclass
class Verdict:
    success: bool | None  # None: unknown
    rationale: str = ""
    latency_s: float = 0.0
    raw: str = ""  # the verifier's whole answer, kept for traces
    score: float | None = None  # confidence of success in [0, 1] when the verifier has one
    input_tokens: int = 0
    output_tokens: int = 0
    cost_usd: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return self.success is True


class Verifier(Protocol):
    name: str
    needs_images: bool  # the loop renders views only for verifiers that look at them

    def atoms_needed(self, request: VerifyRequest, objects: list[str]) -> list[str]:
        """Goal atoms whose truth the loop must put in ``request.scene.facts`` (oracle only)."""
        ...

    async def verify(self, request: VerifyRequest) -> Verdict: ...
