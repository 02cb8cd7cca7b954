"""Ship a `seal train verifier` run as the package's learned verifier, keeping the one it replaces.

A verifier is shipped for the policy it steers, at an operating point, on the strength of its
held-out figures: `ship` copies the run's checkpoint (checked first, so a damaged run never ships)
to ``checkpoints/learned/`` and writes into the copy's manifest the operating point, why it ships,
and the figures of the ``seal bench verifier`` runs that justify it (each bench's JSON, which must
be a bench of this very run). A fresh clone can then say what the shipped verifier scored without
the run directories, which live outside the repository.

The checkpoint it replaces moves to ``checkpoints/<keep_as>/`` and stays loadable as
``learned:<keep_as>``; its manifest gains the label reports give it from then on.
"""

from __future__ import annotations

import json
from datetime import date
from pathlib import Path

from seal.checkpoint import set_aside
from seal.errors import InvalidInput
from seal.verify.learned import CHECKPOINT, DEFAULT_CHECKPOINT

SHIPPED_DIR = DEFAULT_CHECKPOINT.parent
# what a held-out record keeps from a `seal bench verifier` JSON (per-case lists stay with the bench)
BENCH_FIELDS = ("data", "n", "threshold", "accuracy", "precision", "recall", "fp_rate", "confusion", "ci95",
                "per_kind", "per_task", "ms_per_verdict")


def held_out_record(bench: str | Path, run: Path) -> dict:
    """The figures of one `seal bench verifier` JSON, refused unless it benched the checkpoint in ``run``."""
    bench = Path(bench)
    try:
        result = json.loads(bench.read_text())
    except (OSError, ValueError) as exc:
        raise InvalidInput(f"cannot read the bench result {bench}: {exc}") from None
    if not isinstance(result, dict) or "accuracy" not in result:
        raise InvalidInput(f"{bench} is not the JSON `seal bench verifier` prints (no accuracy)")
    spec = str(result.get("verifier", ""))
    benched = Path(spec.split(":", 1)[1]).expanduser().resolve() if spec.startswith("learned:") else None
    if benched != Path(run).resolve():
        raise InvalidInput(f"{bench} benched {spec or 'an unnamed verifier'}, not learned:{run}; bench the run "
                           f"being shipped (`seal bench verifier --verifier learned:{run} ...`)")
    return {k: result[k] for k in BENCH_FIELDS if k in result}


def ship(run: str | Path, *, keep_as: str, operating_point: float, held_out: dict[str, str | Path], why: str,
         keep_label: str | None = None, labels: str = "", root: Path = SHIPPED_DIR) -> Path:
    """Copy the checkpoint of ``run`` to ``root/learned``; the one there moves to ``root/keep_as``.

    ``held_out``: a name per bench JSON (e.g. ``subplan_protocol``, ``task_level``); at least one must be
    measured at ``operating_point``. ``keep_label``: what reports call the kept checkpoint ("learned
    verifier from <keep_label>"). Returns the new checkpoint directory."""
    if not keep_as or "/" in keep_as or keep_as.startswith(".") or keep_as == "learned":
        raise InvalidInput(f"keep_as must be a plain directory name other than 'learned', got {keep_as!r}")
    if not 0.0 < operating_point < 1.0:
        raise InvalidInput(f"the operating point is a threshold in (0, 1), got {operating_point}")
    if not held_out:
        raise InvalidInput("give the held-out bench results the ship rests on (name=BENCH.json)")
    run = Path(run)
    new_digest = CHECKPOINT.digest(run)  # refuses a damaged run before anything is read or moved
    records = {name: held_out_record(path, run) for name, path in held_out.items()}
    if not any(abs(r.get("threshold", -1) - operating_point) < 1e-9 for r in records.values()):
        measured = sorted({r.get("threshold") for r in records.values()}, key=str)
        raise InvalidInput(f"no held-out bench at the operating point {operating_point} (benched at {measured}); "
                           f"the figures that justify an operating point ship with it")
    root = Path(root)
    target = root / "learned"
    replaces = None
    if target.exists():
        replaces = CHECKPOINT.digest(target)
        set_aside(target, root / keep_as, {"replaced_by": new_digest, "replaced_on": date.today().isoformat(),
                                           **({"label": keep_label} if keep_label else {})})
    shipped = {"on": date.today().isoformat(), "from_run": str(run.resolve()),
               **({"replaces": f"{replaces} (now learned:{keep_as})"} if replaces else {}),
               **({"labels": labels} if labels else {}),
               "held_out": records, "operating_point": operating_point, "why": why}
    return CHECKPOINT.install(run, target, {"shipped": shipped})
