"""Ship a trained VLA run as one of the package's named checkpoints, keeping the one it replaces.

`seal train vla` writes a run directory. Shipping copies its checkpoint (checked against its
manifest first, so a damaged run never ships) into ``checkpoints/<name>/`` and writes into the
copy's manifest where the weights came from: the chain of fine-tunes back to the first training,
each link with its command, data sources and shares, code version, steps and held-out figures.
A fresh clone can then say which DAgger rounds a shipped model saw without the run directories,
which live outside the repository.

The checkpoint it replaces moves to ``checkpoints/<keep_as>/`` and stays loadable as
``vla:<keep_as>`` (tables made with it name it by its weights' digest, which the move keeps), and
its manifest gains the label reports give it from then on.
"""

from __future__ import annotations

from datetime import date
from pathlib import Path

from seal.checkpoint import set_aside
from seal.errors import InvalidInput
from seal.policies.vla.locate import CHECKPOINT, SHIPPED_DIR, resolve_checkpoint

# What one link of the chain keeps from its manifest (the rest, e.g. held-out episode lists, stays
# in the run directory).
LINK_FIELDS = ("command", "code_version", "step", "train_config", "sources", "annotations", "train_episodes",
               "heldout", "render", "init_from")
MAX_LINKS = 32  # a chain longer than this is a loop of init_from paths


def lineage(spec: str) -> list[dict]:
    """The checkpoint ``spec`` names and every checkpoint it was fine-tuned from, newest first.

    A link whose checkpoint is gone (a run directory deleted) ends the chain with what its child
    recorded; a link that was itself shipped brings the chain its manifest already holds."""
    links: list[dict] = []
    current: str | None = spec
    while current:
        if len(links) >= MAX_LINKS:
            raise InvalidInput(f"the init_from chain of {spec} is longer than {MAX_LINKS} links: a loop?")
        try:
            path = resolve_checkpoint(current)
        except InvalidInput:
            links.append({"checkpoint": str(current), "missing": True})
            break
        manifest = CHECKPOINT.verify(path)
        link = {"checkpoint": str(current), "digest": CHECKPOINT.digest(path)}
        link |= {k: manifest[k] for k in LINK_FIELDS if k in manifest}
        links.append(link)
        if manifest.get("lineage"):  # a shipped checkpoint: its own chain was recorded when it shipped
            links.extend(manifest["lineage"][1:])
            break
        current = manifest.get("init_from")
    return links


def ship(run: str | Path, name: str, *, keep_as: str | None = None, label: str | None = None,
         keep_label: str | None = None, root: Path = SHIPPED_DIR, note: str = "") -> Path:
    """Copy the checkpoint of ``run`` to ``root/name``; the one there moves to ``root/keep_as``.

    ``label``/``keep_label``: what reports call the new and the kept checkpoint. Returns the new
    checkpoint directory."""
    for n in (name, keep_as):
        if n is not None and (not n or "/" in n or n.startswith(".")):
            raise InvalidInput(f"a shipped checkpoint's name must be a plain directory name, got {n!r}")
    source = resolve_checkpoint(str(run))
    CHECKPOINT.digest(source)  # refuses a damaged run before anything moves
    chain = lineage(str(run))  # before the move: the chain may name the checkpoint being replaced
    root = Path(root)
    target = root / name
    if target.exists():
        if keep_as is None:
            raise InvalidInput(f"{target} holds a shipped checkpoint; give keep_as (a name to keep it loadable "
                               f"under) so tables made with it stay reproducible")
        set_aside(target, root / keep_as, {"replaced_by": chain[0]["digest"], "replaced_on": date.today().isoformat(),
                                           **({"label": keep_label} if keep_label else {})})
    shipped = {"name": name, "from_run": str(Path(run).resolve()), "on": date.today().isoformat()}
    if label:
        shipped["label"] = label
    if note:
        shipped["note"] = note
    return CHECKPOINT.install(source, target, {"shipped": shipped, "lineage": chain})
