"""From a model's reply to checked plans and critical moments.

Two stages. :func:`extract_json` is lenient about the wrapping: code fences, prose before or
after, a trailing comma. :func:`validate` is strict about the content: as many critical moments
as plans, every frame an integer inside the clip, frames never decreasing, and ``time`` within
one frame of ``frame / fps``. Each failure raises :class:`AnswerError` with a message written to
be sent back to the model as is.

Frames may repeat: at 10 fps two short steps can end inside the same 0.1 s frame, and the
expert's own ground truth has such ties. What is never accepted is a step finishing before the
one it follows.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field

from seal.annotate.video import FrameMap
from seal.errors import SealError

# Keys the model may use for the moments list: ours, the seed template's, and obvious variants.
MOMENT_KEYS = ("critical_moments", "critical moments", "critical_moment", "critical moment", "criticalMoments",
               "moments")
TIME_TOLERANCE_FRAMES = 1.0  # |time * fps - frame| allowed: "12.3 s" vs frame 124 is rounding, not a lie

_FENCE = re.compile(r"```(?:json|JSON)?\s*\n?(.*?)```", re.DOTALL)
_TRAILING_COMMA = re.compile(r",\s*([\]}])")


class AnswerError(SealError, ValueError):
    """A reply that does not meet the annotation contract; the message says what is wrong."""


@dataclass
class Annotation:
    """Plans and, per plan, when it finished: in clip frames, seconds and dataset frames."""

    plans: list[str]
    video_frames: list[int]
    times: list[float]
    dataset_frames: list[int] = field(default_factory=list)

    def moments(self) -> list[dict]:
        return [{"time": t, "frame": v, "dataset_frame": d}
                for t, v, d in zip(self.times, self.video_frames, self.dataset_frames)]


def extract_json(text: str) -> dict:
    """The first JSON object in ``text``: inside a code fence if there is one, else anywhere."""
    if not isinstance(text, str) or not text.strip():
        raise AnswerError("the reply is empty; expected a JSON object")
    candidates = [m.group(1) for m in _FENCE.finditer(text)] + [text]
    decoder = json.JSONDecoder()
    for chunk in candidates:
        for start in (i for i, c in enumerate(chunk) if c == "{"):
            for attempt in (chunk[start:], _TRAILING_COMMA.sub(r"\1", chunk[start:])):
                try:
                    obj, _ = decoder.raw_decode(attempt)
                except json.JSONDecodeError:
                    continue
                if isinstance(obj, dict):
                    return obj
    preview = text.strip().replace("\n", " ")[:120]
    raise AnswerError(f"no JSON object found in the reply (it starts: {preview!r})")


def _moments_list(obj: dict) -> list:
    for key in MOMENT_KEYS:
        if key in obj:
            return obj[key]
    raise AnswerError(f"the JSON object has no \"critical_moments\" list (its keys: {sorted(obj)})")


def _number(value, what: str) -> float:
    if isinstance(value, bool):
        raise AnswerError(f"{what} is {value!r}; expected a number")
    if isinstance(value, str):
        try:
            value = float(value.strip().rstrip("s").strip())
        except ValueError:
            raise AnswerError(f"{what} is {value!r}; expected a number") from None
    if not isinstance(value, (int, float)) or not math.isfinite(value):
        raise AnswerError(f"{what} is {value!r}; expected a number")
    return float(value)


def clean_plan(text: str) -> str:
    """A plan as stored: single spaces, no list numbering, no final period (the reasoning text
    adds its own punctuation, see ``Reasoning.text``)."""
    text = " ".join(str(text).split())
    text = re.sub(r"^(?:step\s*)?\d+\s*[.):-]\s*", "", text, flags=re.IGNORECASE)
    return text.rstrip(" .;")


def validate(obj: dict, frame_map: FrameMap) -> Annotation:
    """Check a parsed reply against the clip; raise AnswerError naming the first problem."""
    n, fps = frame_map.num_video_frames, frame_map.video_fps
    if not isinstance(obj, dict):
        raise AnswerError(f"expected a JSON object, got {type(obj).__name__}")
    plans = obj.get("plans")
    if not isinstance(plans, list) or not plans:
        raise AnswerError("\"plans\" must be a non-empty list of step descriptions")
    cleaned = []
    for k, p in enumerate(plans):
        if not isinstance(p, str) or not clean_plan(p):
            raise AnswerError(f"plans[{k}] is {p!r}; every plan must be a non-empty string")
        cleaned.append(clean_plan(p))
    moments = _moments_list(obj)
    if not isinstance(moments, list):
        raise AnswerError("\"critical_moments\" must be a list of {\"time\": ..., \"frame\": ...} objects")
    if len(moments) != len(plans):
        raise AnswerError(f"there are {len(plans)} plans but {len(moments)} critical moments; "
                          f"give exactly one critical moment per plan")
    frames, times = [], []
    for k, m in enumerate(moments):
        if not isinstance(m, dict) or "frame" not in m or "time" not in m:
            raise AnswerError(f"critical_moments[{k}] is {json.dumps(m)[:80]}; expected an object with "
                              f"\"time\" and \"frame\"")
        frame = _number(m["frame"], f"critical_moments[{k}].frame")
        time = _number(m["time"], f"critical_moments[{k}].time")
        if frame != int(frame):
            raise AnswerError(f"critical_moments[{k}].frame is {m['frame']!r}; frames are whole numbers")
        frame = int(frame)
        if not 0 <= frame < n:
            raise AnswerError(f"critical_moments[{k}].frame is {frame}, outside the video; "
                              f"valid frames are 0 to {n - 1}")
        if abs(time * fps - frame) > TIME_TOLERANCE_FRAMES + 1e-6:
            raise AnswerError(f"critical_moments[{k}] has time {time:g} s but frame {frame}; at {fps} fps "
                              f"frame {frame} is at {frame / fps:.1f} s")
        if frames and frame < frames[-1]:
            raise AnswerError(f"critical_moments[{k}].frame is {frame}, earlier than the previous step's "
                              f"frame {frames[-1]}; steps finish in order")
        frames.append(frame)
        times.append(round(time, 3))
    return Annotation(plans=cleaned, video_frames=frames, times=times,
                      dataset_frames=[frame_map.dataset_frame(v) for v in frames])


def parse_answer(text: str, frame_map: FrameMap) -> Annotation:
    """extract_json + validate."""
    return validate(extract_json(text), frame_map)
