"""The annotation question.

Same structure as the appendix template of the paper (task goal; plans written from the goal
alone as short actions; one critical moment per plan, given as ``time`` and ``frame`` of a 10 fps
video; JSON only), in our own words. We also say how many frames the clip has, so the model
knows the valid range, and name the JSON keys exactly. The reply contract is checked by
:mod:`seal.annotate.parse`; an answer that breaks it is sent back with :func:`retry_message`.
"""

from __future__ import annotations

PROMPT_VERSION = 1  # part of the cache key: bump when the wording changes

_TEMPLATE = """\
You are watching a short video of a robot arm doing a manipulation task on a table. Work out \
the steps the task needs, then follow the video and find when each step is completed.

Task goal: {instruction}

Plans: list the steps needed to reach the task goal, in order. Write each step as a short \
action phrase such as "pick up the bowl", "place it on the plate", "open the drawer", \
"close the microwave" or "move the pot to the stove". Derive the steps from the task goal \
alone, before looking at the video.

Critical moments: for every step, give the moment in the video at which that step is \
completed, as "time" (seconds from the start, written like 12.3, to one decimal place) and \
"frame" (the frame number in this video, which runs at {fps} frames per second, so frame = \
time x {fps}). The video has {n_frames} frames, numbered 0 to {last_frame} ({duration:.1f} s). \
Give exactly one critical moment per step, in the same order as the steps, so both lists have \
the same length; a later step never finishes before an earlier one.

Reply with one JSON object and nothing else - no explanation, no markdown:
{{"plans": ["<step 1>", "<step 2>", ...], "critical_moments": [{{"time": <seconds>, "frame": <frame>}}, ...]}}

Keep every step brief and precise. Now watch the video closely."""

_RETRY = """\
Your previous reply could not be used: {error}
Answer the same question again. Reply with only the JSON object \
{{"plans": [...], "critical_moments": [{{"time": ..., "frame": ...}}, ...]}}, with one critical \
moment per step and every frame between 0 and {last_frame}."""


def build_prompt(instruction: str, n_frames: int, fps: int = 10) -> str:
    """The question for one episode: its instruction and the clip's length in frames."""
    return _TEMPLATE.format(instruction=instruction.strip().rstrip("."), fps=fps, n_frames=n_frames,
                            last_frame=n_frames - 1, duration=(n_frames - 1) / fps)


def retry_message(error: str, n_frames: int) -> str:
    """The follow-up turn after an answer failed validation: the exact problem, then the contract."""
    return _RETRY.format(error=error, last_frame=n_frames - 1)


def frame_label(v: int, fps: int = 10) -> str:
    """The caption put before each image when frames are sent as images (OpenAI backend)."""
    return f"Frame {v} (time {v / fps:.1f} s):"
