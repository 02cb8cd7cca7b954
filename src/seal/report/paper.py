"""The paper's published per-task success rates (shipped as ``seal/data/paper_results.csv``).

The csv already uses this project's suite names (libero_10, lang_rephrase, lang_object_property,
visual_scene, visual_viewpoint, composition); what differs is the method naming and that several
training sets are reported. Our methods sit beside the paper's as follows: ``base`` is the
reasoning VLA without steering (``pi0_reason``), except the shipped twin (the VLA trained without
reasoning), which stands for the paper's plain ``pi0``; ``value`` is V-GPS (``pi0_vgps``), ``seal``
is ``seal``; our ``random`` has no counterpart.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from importlib import resources

from seal.errors import InvalidInput
from seal.report.labels import KnownVLA, is_twin, shipped_vlas

PAPER_METHOD = {"base": "pi0_reason", "value": "pi0_vgps", "seal": "seal"}
PAPER_NAMES = {"pi0": "π0", "pi0_vgps": "π0+V-GPS", "pi0_reason": "π0-reason", "seal": "SEAL"}
PAPER_ORDER = ("pi0", "pi0_vgps", "pi0_reason", "seal")  # the columns of Tables II, VII and VIII
# LIBERO-100 is the only training set every table reports (Table II also has LIBERO-10 and
# LIBERO-100+basket; Table VIII reports a task subset for those two).
DEFAULT_TRAINING = "libero_100"
TABLES = {"libero_10": "Table II", "lang_rephrase": "Table VII", "lang_object_property": "Table VII",
          "visual_scene": "Table VII", "visual_viewpoint": "Table VII", "composition": "Table VIII"}


@dataclass(frozen=True)
class PaperResults:
    """(suite, training set, task, paper method) -> success in percent."""

    rates: dict[tuple[str, str, int, str], float]

    @classmethod
    def load(cls) -> PaperResults:
        text = (resources.files("seal") / "data" / "paper_results.csv").read_text()
        rates = {}
        for rec in csv.DictReader(text.splitlines()):
            key = (rec["suite"], rec["training_data"], int(rec["task_id"]), rec["method"])
            rates[key] = float(rec["success_pct"])
        return cls(rates)

    @property
    def training_sets(self) -> list[str]:
        return sorted({k[1] for k in self.rates})

    def check_training(self, training: str) -> None:
        if training not in self.training_sets:
            raise InvalidInput(f"unknown paper training set {training!r}; valid: {', '.join(self.training_sets)}")

    def rate(self, suite: str, training: str, task: int, paper_method: str) -> float | None:
        return self.rates.get((suite, training, task, paper_method))

    def has_suite(self, suite: str, training: str) -> bool:
        return any(k[0] == suite and k[1] == training for k in self.rates)


def paper_method_for(config: dict, vlas: dict[str, KnownVLA] | None = None) -> str | None:
    """The paper method shown beside one of ours, or None. ``vlas``: the VLA checkpoints known by
    name (default: the shipped ones), which tell the twin from the reasoning VLA."""
    method = config.get("method", "")
    if method == "base" and config.get("policy") == "vla":
        if is_twin(config, shipped_vlas() if vlas is None else vlas):
            return "pi0"
    return PAPER_METHOD.get(method)
