"""Structured episode traces: one JSON object per line, written as events happen.

Events: ``subplan`` (reasoning at a sub-plan start), ``candidate`` (one per candidate per round:
how it ended, its verdict with rationale, its end snapshot id, timestamps), ``commit`` (the
winner), ``episode_end``. Timestamps are seconds since the trace was opened, so verification
overlap and early exit can be read off directly.

Clock readings sit in their own fields, `TIMING_FIELDS`: ``t`` (every event), ``t_start``,
``t_end``, ``t_verified`` (candidates) and a verdict's ``latency_s``. Nothing else in a trace
reads a clock, so with verdicts taken in slot order (``verify_order="slot"``, `seal eval`'s
default) two runs of the same episode write the same trace once `without_timing` has dropped
them (`same_episode` compares two trace files so).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

EVENTS = ("subplan", "candidate", "commit", "done_check", "episode_end")  # what a trace file holds
# The fields that hold clock readings (seconds), at any depth of an event: all that may differ
# between two runs of the same episode in slot order.
TIMING_FIELDS = frozenset({"t", "t_start", "t_end", "t_verified", "latency_s"})


class Trace:
    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "w")
        self._t0 = time.perf_counter()

    def write(self, event: str, **fields) -> None:
        for key in ("t_start", "t_end", "t_verified"):
            if fields.get(key):
                fields[key] = round(fields[key] - self._t0, 4)
        record = {"event": event, "t": round(time.perf_counter() - self._t0, 4), **fields}
        # strict JSON: a non-finite number (a broken model's score) is written as null, never as a bare NaN
        self._file.write(json.dumps(_finite(record), default=_plain, allow_nan=False) + "\n")
        self._file.flush()  # a crash keeps everything up to the last event

    def on_event(self, event: str, fields: dict) -> None:
        """As a loop subscriber (`seal.steer.events`): every event but the in-memory ``round_end``."""
        if event in EVENTS:
            self.write(event, **fields)

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> "Trace":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_trace(path: Path, *, strict: bool = True) -> list[dict]:
    """The events of a trace. ``strict=False`` skips lines that are not JSON (a process killed
    mid-write leaves half a line) instead of raising; readers that show traces use it."""
    events = []
    for line in Path(path).read_text().splitlines():
        if not line.strip():
            continue
        try:
            events.append(json.loads(line))
        except json.JSONDecodeError:
            if strict:
                raise
    return events


def without_timing(obj):
    """A trace's events (or one event, or any JSON value) without the `TIMING_FIELDS`."""
    if isinstance(obj, dict):
        return {k: without_timing(v) for k, v in obj.items() if k not in TIMING_FIELDS}
    if isinstance(obj, list):
        return [without_timing(v) for v in obj]
    return obj


def same_episode(a: Path, b: Path) -> bool:
    """Two trace files that differ at most in their clock readings."""
    return without_timing(read_trace(a)) == without_timing(read_trace(b))


def _finite(obj):
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):
        return _finite(obj.tolist())
    return obj


def _plain(obj):
    if hasattr(obj, "tolist"):
        return obj.tolist()
    return str(obj)
