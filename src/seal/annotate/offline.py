"""The offline annotator: the expert's recorded sub-plans and true sub-goal times as the answer.

It writes the reply a perfect model would give (the same JSON, at 10 fps) and sends it through
the same parser and checks as a model's reply, so the offline path exercises everything but the
network. The dataset frames of its critical moments are then set to the exact recorded ones
(the 10 fps clip cannot express an odd 20 fps frame), which makes its chunk labels equal the
ground truth by construction: ``seal bench annotate --backend offline`` checks that they do.
"""

from __future__ import annotations

import json

from seal.annotate.base import DEFAULT_MODELS, AnnotatorResult, EpisodeInput
from seal.annotate.parse import AnswerError, parse_answer


class OfflineAnnotator:
    backend = "offline"
    model = DEFAULT_MODELS["offline"]
    needs_clip = False

    async def annotate(self, job: EpisodeInput) -> AnnotatorResult:
        plans, frames = job.truth_plans or [], job.truth_frames or []
        if not plans:
            return AnnotatorResult(status="failed", error=f"episode {job.episode} has no recorded sub-plans "
                                   f"(the offline annotator needs a dataset recorded by `seal demos record`)")
        if len(plans) != len(frames):
            return AnnotatorResult(status="failed", error=f"episode {job.episode} has {len(plans)} sub-plans but "
                                   f"{len(frames)} critical frames")
        never = [p for p, f in zip(plans, frames) if f < 0]
        if never:
            return AnnotatorResult(status="failed", error=f"episode {job.episode}: sub-plan(s) {never} never held "
                                   f"in the recording, so they have no critical moment")
        fm = job.frame_map
        video = [fm.first_showing(f) for f in frames]
        raw = json.dumps({"plans": plans, "critical_moments": [{"time": fm.time_of(v), "frame": v} for v in video]})
        try:
            annotation = parse_answer(raw, fm)
        except AnswerError as exc:  # e.g. the recording's frames are out of order
            return AnnotatorResult(status="failed", raw=[raw], error=f"ground truth fails the checks: {exc}")
        annotation.plans = list(plans)  # verbatim, so labels equal the expert's text exactly
        annotation.dataset_frames = [int(f) for f in frames]
        return AnnotatorResult(status="ok", annotation=annotation, raw=[raw])

    async def aclose(self) -> None:
        return None
