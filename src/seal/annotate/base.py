"""What every annotator shares: the job it gets, the result it returns, the protocol.

Kept apart from the VLM backends (`backends.py`) so the offline annotator (`offline.py`) and
the backends do not import each other.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from seal.annotate.parse import Annotation
from seal.annotate.video import FrameMap

BACKENDS = ("gemini", "openai", "offline")
DEFAULT_MODELS = {"gemini": "gemini-2.5-pro", "openai": "gpt-4o", "offline": "expert-ground-truth"}



@dataclass
class EpisodeInput:
    """What an annotator gets for one episode."""

    episode: int
    instruction: str
    frame_map: FrameMap
    clip: np.ndarray | None = None  # (n, H, W, 3) uint8 at 10 fps; None for the offline annotator
    clip_path: Path | None = None  # the same clip as mp4 (what Gemini uploads)
    truth_plans: list[str] | None = None  # the expert's sub-plans, when the dataset has them
    truth_frames: list[int] | None = None  # dataset frame where each first held, -1 never


@dataclass
class AnnotatorResult:
    status: str  # "ok" | "failed"
    annotation: Annotation | None = None
    raw: list[str] = field(default_factory=list)  # every reply, in order
    error: str = ""
    calls: list[dict] = field(default_factory=list)  # one log row per wire call
    cached: bool = False

    @property
    def input_tokens(self) -> int:
        return sum(c.get("input_tokens", 0) for c in self.calls)

    @property
    def output_tokens(self) -> int:
        return sum(c.get("output_tokens", 0) for c in self.calls)

    @property
    def cost_usd(self) -> float:
        return sum(c.get("cost_usd", 0.0) for c in self.calls)


class Annotator(Protocol):
    backend: str
    model: str
    needs_clip: bool  # whether EpisodeInput.clip / clip_path must be filled (decode video)

    async def annotate(self, job: EpisodeInput) -> AnnotatorResult: ...

    async def aclose(self) -> None: ...
