"""The value plug-in of the steering loop's scorer seam (`seal.steer.scoring`): V-GPS at run time.

- `inputs`: what the value function sees of a step (agent view at 56 px, the executed chunk);
- `vgps`: the Q-network, its checkpoint files and `VGPSScorer` (PyTorch);
- here: the checkpoint directory's layout, which the loop's config hash reads without PyTorch.

Like a policy or a verifier, it sits below the loop that names it in a registry
(``SCORERS["value"]``); `seal.train.vgps` trains it.
"""

from __future__ import annotations

from pathlib import Path

from seal.errors import InvalidInput

# A V-GPS checkpoint directory (`seal train value` writes one into its run directory): the
# networks' weights, what shapes them, and the manifest that vouches for both (`seal.checkpoint`).
VALUE_KIND = "seal-vgps"
VALUE_WEIGHTS, VALUE_CONFIG = "value.safetensors", "value.json"
VALUE_FILES = (VALUE_WEIGHTS, VALUE_CONFIG)


def value_directory(path: str | Path) -> Path:
    """A V-GPS checkpoint directory from a run directory or one of its files."""
    p = Path(path)
    p = p.parent if p.is_file() else p
    if not (p / VALUE_WEIGHTS).is_file() and not (p / "manifest.json").is_file():
        raise InvalidInput(f"no V-GPS checkpoint at {p} (no {VALUE_WEIGHTS}); train one with `seal train value`")
    return p
