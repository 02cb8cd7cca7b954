"""Where a VLA checkpoint is, and what identifies its weights; no torch needed (the method
description hashes a checkpoint without loading a model).

``vla`` alone means the shipped reasoning model; ``vla:twin`` and ``vla:reason`` name the two
shipped checkpoints, and every other directory of ``checkpoints/`` is loadable by its name too
(``vla:reason_r0``: a checkpoint kept when a retrained one replaced it, `seal.policies.vla.ship`);
anything else after the colon is a checkpoint directory (a `seal train vla` run directory holds
one in ``checkpoint/``, which is used when given the run directory).
"""

from __future__ import annotations

import json
from pathlib import Path

from seal.checkpoint import MANIFEST, CheckpointFormat
from seal.errors import InvalidInput

SHIPPED_DIR = Path(__file__).resolve().parent / "checkpoints"
# The two current checkpoints, then any kept under another name (read once: the package's files)
SHIPPED = {"reason": SHIPPED_DIR / "reason", "twin": SHIPPED_DIR / "twin",
           **{p.name: p for p in sorted(SHIPPED_DIR.glob("*/")) if not p.name.startswith(".") and (p / MANIFEST).is_file()}}
FORMAT = 1
KIND = "seal-vla"
WEIGHTS, CONFIG, TOKENIZER = "model.safetensors", "config.json", "tokenizer.json"
FILES = (WEIGHTS, CONFIG, TOKENIZER)  # what a checkpoint's manifest must vouch for
CHECKPOINT = CheckpointFormat(KIND, required=FILES, named_by=(WEIGHTS,))  # named by the weights' sha256
RUN_CHECKPOINT = "checkpoint"  # inside a `seal train vla` run directory


def resolve_checkpoint(spec: str = "") -> Path:
    """'' or 'reason' or 'twin' (shipped) or a directory -> the checkpoint directory."""
    spec = (spec or "reason").strip()
    if spec in SHIPPED:
        path = SHIPPED[spec]
        if not (path / MANIFEST).is_file():
            raise InvalidInput(f"no shipped checkpoint yet at {path}; train one with `seal train vla` "
                               f"or pass vla:PATH")
        return path
    path = Path(spec).expanduser()
    if (path / RUN_CHECKPOINT / MANIFEST).is_file():
        return path / RUN_CHECKPOINT
    if not (path / MANIFEST).is_file():
        raise InvalidInput(f"no VLA checkpoint at {path} (no {MANIFEST}); train one with `seal train vla` "
                           f"or pass vla:PATH with a checkpoint directory")
    return path


def checkpoint_digest(spec: str = "") -> str:
    """What identifies the weights: the first 12 hex digits of their sha256, taken from the file
    after the whole checkpoint was checked against its manifest (a damaged copy is refused, never
    filed under the genuine one's name), so retraining in place is a new method in a store."""
    return CHECKPOINT.digest(resolve_checkpoint(spec))


def trained_render(spec: str = "") -> dict:
    """The render model a checkpoint's demonstrations were recorded in: ``{"mode": "stock"|"fast",
    "fast_version": int|None, "recorded": bool}`` from its manifest (``stock`` and ``recorded`` False
    when the manifest predates the field)."""
    path = resolve_checkpoint(spec)
    try:
        render = json.loads((path / MANIFEST).read_text()).get("render") or {}
    except json.JSONDecodeError as exc:
        raise InvalidInput(f"{path / MANIFEST} is not valid JSON ({exc})") from None
    return {"mode": render.get("mode", "stock"), "fast_version": render.get("fast_version"), "recorded": bool(render)}
