"""The value plug-in of the steering loop's scorer seam (`seal.steer.scoring`): V-GPS at run time.

- `inputs`: what the value function sees of a step (agent view at 56 px, the executed chunk);
- `vgps`: the Q-network, its checkpoint files and `VGPSScorer` (PyTorch);
- here: the checkpoint directory's layout, which the loop's config hash reads without PyTorch.

Like a policy or a verifier, it sits below the loop that names it in a registry
(``SCORERS["value"]``); `seal.train.vgps` trains it. The package ships a trained Q-function in
``checkpoints/`` (``value_ckpt`` unset, or its name), so a fresh clone runs V-GPS without training;
`seal.value.ship` puts a `seal train value` run there.
"""

from __future__ import annotations

from pathlib import Path

from seal.checkpoint import CheckpointFormat
from seal.errors import InvalidInput

# A V-GPS checkpoint directory (`seal train value` writes one into its run directory): the
# networks' weights, what shapes them, and the manifest that vouches for both (`seal.checkpoint`).
VALUE_KIND = "seal-vgps"
VALUE_WEIGHTS, VALUE_CONFIG = "value.safetensors", "value.json"
VALUE_FILES = (VALUE_WEIGHTS, VALUE_CONFIG)
# what names a value checkpoint in a results store: sha1 of its verified weights and config
VALUE_CHECKPOINT = CheckpointFormat(VALUE_KIND, required=VALUE_FILES, named_by=VALUE_FILES, algorithm="sha1")

SHIPPED_DIR = Path(__file__).resolve().parent / "checkpoints"
# The Q-function V-GPS uses when no checkpoint is named: IQL on LIBERO-10 demonstrations plus the twin's
# own rollouts, failures included. The demonstrations-only one (the paper's recipe, `l10_demos`) ranked
# the twin's held-out chunks no better than chance (docs/performance.md). Other directories of
# checkpoints/ load by their names.
DEFAULT_SHIPPED = "l10_twin_rollouts"


def shipped() -> dict[str, Path]:
    """The package's value checkpoints by name (read from the package's files on each call)."""
    return {p.name: p for p in sorted(SHIPPED_DIR.glob("*/")) if not p.name.startswith(".")}


def value_directory(path: str | Path = "") -> Path:
    """A V-GPS checkpoint directory from '' (the shipped default), a shipped name, a run directory
    or one of its files."""
    names, name = shipped(), str(path) or DEFAULT_SHIPPED
    if not str(path) or name in names:
        if name not in names:
            raise InvalidInput(f"no shipped V-GPS checkpoint {name!r} in {SHIPPED_DIR} (shipped: "
                               f"{', '.join(names) or 'none'}); train one with `seal train value` and pass "
                               "value_ckpt=RUN_DIR")
        return names[name]
    p = Path(path)
    p = p.parent if p.is_file() else p
    if not (p / VALUE_WEIGHTS).is_file() and not (p / "manifest.json").is_file():
        raise InvalidInput(f"no V-GPS checkpoint at {p} (no {VALUE_WEIGHTS}); train one with `seal train value`")
    return p
