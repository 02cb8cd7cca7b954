"""Ship a `seal train value` run as one of the package's named Q-functions (``checkpoints/<name>/``).

The run is checked against its manifest before anything is copied, and the copy again before it
takes its name, so a damaged run never ships. The copy's manifest records where it came from: the
run, its training data and settings, its held-out figures (the run's ``summary.json``) and a note.
A name is never shipped over: every shipped Q-function stays loadable by its name, so the tables
made with it stay reproducible; pointing ``DEFAULT_SHIPPED`` at a new one is a reviewed code change.
"""

from __future__ import annotations

import json
from datetime import date
from pathlib import Path

from seal.errors import InvalidInput
from seal.value import SHIPPED_DIR, VALUE_CHECKPOINT, value_directory

# the run's summary fields worth keeping once the run directory is gone
SUMMARY_FIELDS = ("dataset", "image_size", "goals", "config", "heldout", "heldout_rollouts", "train_fit",
                  "rollouts", "rollout_transitions")


def ship(run: str | Path, name: str, *, root: Path = SHIPPED_DIR, note: str = "") -> Path:
    """Copy the checkpoint of ``run`` to ``root/name``; returns that directory."""
    if not name or "/" in name or name.startswith("."):
        raise InvalidInput(f"a shipped checkpoint's name must be a plain directory name, got {name!r}")
    if not str(run):
        raise InvalidInput("give the `seal train value` run directory to ship")
    source = value_directory(run)
    digest = VALUE_CHECKPOINT.digest(source)  # refuses a damaged run before anything is copied
    target = Path(root) / name
    if target.exists():
        raise InvalidInput(f"{target} holds a shipped Q-function already; ship under another name")
    summary_path = source / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    shipped = {"name": name, "from_run": str(source.resolve()), "on": date.today().isoformat(), "digest": digest,
               **({"note": note} if note else {})}
    return VALUE_CHECKPOINT.install(source, target, {"shipped": shipped, "training": {
        k: summary[k] for k in SUMMARY_FIELDS if k in summary}})
