"""Checks for the fields of a training config, so a bad value is refused when the config is made
(before minutes of data loading), with the field's name, the value and what is valid."""

from __future__ import annotations

import math

import numpy as np

from seal.errors import InvalidInput


def check_integer(config, name: str, low: int, high: int | None = None, what: str = "") -> None:
    v = getattr(config, name)
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low or (high is not None and v > high):
        valid = f">= {low}" if high is None else f"in {low}..{high}"
        raise InvalidInput(f"{name} must be an integer {valid}{what}, got {v!r}")


def check_real(config, name: str, ok, valid: str) -> None:
    v = getattr(config, name)
    if isinstance(v, bool) or not isinstance(v, (int, float, np.number)) or not math.isfinite(float(v)) \
            or not ok(float(v)):
        raise InvalidInput(f"{name} must be {valid}, got {v!r}")
