"""A results database read once into what every report part needs: methods in a stable order,
per-cell counts, paired outcomes and the trial files on disk.

Error trials (``status='error'``: the harness caught a crash) count as failures everywhere, as they
would for a robot that crashed mid-task; they are also listed separately so nobody mistakes a
broken run for a bad method.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import re
from collections import Counter, defaultdict
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from seal.errors import InvalidInput
from seal.eval.store import ResultStore, TrialRow
from seal.report.labels import display_name, shipped_vlas
from seal.report.paper import PAPER_ORDER, paper_method_for
from seal.report.stats import wilson

SUITE_ORDER = ("libero_10", "lang_rephrase", "lang_object_property", "visual_scene", "visual_viewpoint",
               "composition")
METHOD_ORDER = ("base", "random", "value", "seal")
# The visual suites change the scene, not the words: their instructions are LIBERO-10's.
INSTRUCTIONS_FROM = {"visual_scene": "libero_10", "visual_viewpoint": "libero_10"}
# A stored trial file's path ends in suite/task/method-hash/trialNNN/<file>: the part that stays when the
# run directory moves.
TRIAL_FILE_PARTS = 5


@dataclass(frozen=True)
class MethodInfo:
    """One method configuration (a column of the tables).

    ``label`` is the name a person would write ("reasoning VLA + SEAL (oracle)", see
    `seal.report.labels`), unique within a report; ``spec_label`` is what `seal eval` stored
    (``seal[k=2]``); ``family`` the label without K (configs that differ only in K form one line in
    runtime-vs-K plots); ``paper_method`` the paper's column beside it, if any.
    """

    config_hash: str
    label: str
    config: dict
    spec_label: str = ""
    family: str = ""
    paper_method: str | None = None

    @property
    def method(self) -> str:
        return str(self.config.get("method") or self.spec_label.split("[")[0])

    @property
    def k(self) -> int:
        """Candidates per sub-plan; base runs one."""
        return 1 if self.method == "base" else int(self.config.get("k", 1))


@dataclass
class Cell:
    """Trials of one method on one task (or pooled over a suite)."""

    n: int = 0
    successes: int = 0
    errors: int = 0
    sim_errors: int = 0

    def add(self, row: TrialRow) -> None:
        self.n += 1
        self.successes += int(succeeded(row))
        self.errors += row.status == "error"
        self.sim_errors += bool(row.sim_error)

    @property
    def rate(self) -> float:
        return self.successes / self.n if self.n else math.nan

    @property
    def ci(self) -> tuple[float, float]:
        return wilson(self.successes, self.n)


def succeeded(row: TrialRow) -> bool:
    return bool(row.success) and row.status == "ok"


class ReportData:
    """Everything the report reads from one results database."""

    def __init__(self, db: str | Path, *, runs_dir: str | Path | None = None, suites: list[str] | None = None,
                 methods: list[str] | None = None):
        """``suites``: report only these (a run still under way in others, say); default all.
        ``methods``: report only the method configurations each item names: its readable label (any case),
        a part of the stored method string (``policy_ckpt=563400068f48``) or a config-hash prefix; default all."""
        self.db_path = Path(db)
        with ResultStore(self.db_path, create=False) as store:
            self.rows = store.rows()
            registered = store.methods()
        if not self.rows:
            raise InvalidInput(f"{self.db_path} holds no finished trials yet; run `seal eval` first")
        if suites:
            stored = sorted({r.suite for r in self.rows})
            unknown = [s for s in suites if s not in stored]
            if unknown:
                raise InvalidInput(f"no trials of suite(s) {', '.join(unknown)} in {self.db_path}; "
                                   f"it holds: {', '.join(stored)}")
            self.rows = [r for r in self.rows if r.suite in suites]
        self.runs_dir = Path(runs_dir) if runs_dir else default_runs_dir(self.db_path)
        self.methods = _method_list(self.rows, registered)
        if methods:
            keep = set()
            for item in methods:
                hit = {m.config_hash for m in self.methods if _names(m, item)}
                if not hit:
                    raise InvalidInput(f"--methods {item!r} names no method in {self.db_path}; it holds: "
                                       + "; ".join(f"{m.label} ({m.spec_label}, {m.config_hash[:8]})"
                                                   for m in self.methods))
                keep |= hit
            self.rows = [r for r in self.rows if r.config_hash in keep]
            self.methods = [m for m in self.methods if m.config_hash in keep]
        self.by_hash = {m.config_hash: m for m in self.methods}
        self.suites = sorted({r.suite for r in self.rows},
                             key=lambda s: (SUITE_ORDER.index(s) if s in SUITE_ORDER else len(SUITE_ORDER), s))
        self._cells: dict[tuple[str, int, str], Cell] = defaultdict(Cell)
        self._outcome: dict[tuple[str, str, int, int], bool] = {}
        for r in self.rows:
            self._cells[(r.suite, r.task, r.config_hash)].add(r)
            self._outcome[(r.config_hash, r.suite, r.task, r.trial)] = succeeded(r)
        self.instructions = _instructions()

    # ---- layout ----------------------------------------------------------------------------
    def tasks(self, suite: str) -> list[int]:
        return sorted({r.task for r in self.rows if r.suite == suite})

    def methods_in(self, suite: str | None = None) -> list[MethodInfo]:
        present = {r.config_hash for r in self.rows if suite is None or r.suite == suite}
        return [m for m in self.methods if m.config_hash in present]

    def instruction(self, suite: str, task: int) -> str:
        return self.instructions.get((INSTRUCTIONS_FROM.get(suite, suite), task), "")

    # ---- counts ----------------------------------------------------------------------------
    def cell(self, suite: str, task: int, config_hash: str) -> Cell:
        return self._cells.get((suite, task, config_hash), Cell())

    def pooled(self, config_hash: str, suite: str | None = None) -> Cell:
        """All trials of a method in a suite (or everywhere): the 'Average' row."""
        out = Cell()
        for r in self.rows:
            if r.config_hash == config_hash and (suite is None or r.suite == suite):
                out.add(r)
        return out

    def pairs(self, hash_a: str, hash_b: str, suite: str | None = None,
              task: int | None = None) -> list[tuple[bool, bool]]:
        """(A succeeded, B succeeded) on every (suite, task, trial) both methods ran (within one
        suite, or one task of it, if given): the same init state and seed, so the comparison is paired."""
        return self.outcomes([hash_a, hash_b], suite, task)

    def outcomes(self, hashes: list[str], suite: str | None = None, task: int | None = None) -> list[tuple[bool, ...]]:
        """One tuple of successes (in ``hashes``' order) per (suite, task, trial) every method ran."""
        out = []
        for (h, s, t, trial), ok in sorted(self._outcome.items()):
            if h != hashes[0] or (suite is not None and s != suite) or (task is not None and t != task):
                continue
            others = [self._outcome.get((o, s, t, trial)) for o in hashes[1:]]
            if None not in others:
                out.append((ok, *others))
        return out

    def label_of(self, row: TrialRow) -> str:
        """The readable name of a trial's method (its stored label if the store never registered it)."""
        info = self.by_hash.get(row.config_hash)
        return info.label if info else row.method

    def errors(self) -> list[TrialRow]:
        return [r for r in self.rows if r.status == "error"]

    def verifier_trouble(self) -> list[TrialRow]:
        """Trials in which some verification got no answer (transient errors past the retries)."""
        return [r for r in self.rows if r.verifier_errors > 0 or r.verifier_unavailable]

    def verifier_warning(self) -> str:
        """One sentence for the top of the report, or "" when every verification was answered."""
        trouble = self.verifier_trouble()
        if not trouble:
            return ""
        calls = sum(r.verifier_errors for r in trouble)
        mostly = sum(r.verifier_unavailable for r in trouble)
        return (f"Warning: {calls} verification(s) in {len(trouble)} trial(s) got no answer from the verifier "
                f"(errors that outlasted the retries; the loop fell back to unverified candidates there). "
                f"{mostly} trial(s) had the verifier unavailable in most of their rounds (no answer at all): their results "
                f"say little about the verified method. See the table 'Verifier errors'.")

    def ended_by(self, row: TrialRow) -> str:
        """Why a trial's episode stopped: the stored value, else the trace's ``episode_end`` event
        (traces carried it before the results store did), else "not recorded"."""
        if row.status == "error":
            return "error"
        if row.ended_by:
            return row.ended_by
        trace = self.resolve(row.trace_path)
        if trace is not None:
            end = _last_event(trace)
            if end.get("event") == "episode_end" and end.get("ended_by"):
                return str(end["ended_by"])
        return "not recorded"

    # ---- files -----------------------------------------------------------------------------
    def resolve(self, stored: str) -> Path | None:
        """A trial file as stored, or the same file under ``runs_dir`` if the run directory was
        moved or copied (stored paths end in suite/task/method-hash/trialNNN/<file>)."""
        if not stored:
            return None
        path = Path(stored)
        if path.exists():
            return path
        parts = path.parts
        for tail in (TRIAL_FILE_PARTS, TRIAL_FILE_PARTS + 1):  # trace.jsonl / episode.mp4, grids/<png>
            if len(parts) >= tail:
                moved = self.runs_dir.joinpath(*parts[-tail:])
                if moved.exists():
                    return moved
        return None


def default_runs_dir(db: str | Path) -> Path:
    """Where a results database's trial files are looked for when their stored paths are gone."""
    return Path(str(Path(db).with_suffix("")) + "_runs")


def _last_event(trace: Path) -> dict:
    """The last JSON line of a trace, read from the file's end (traces grow to megabytes)."""
    with open(trace, "rb") as f:
        f.seek(0, 2)
        f.seek(max(0, f.tell() - 16384))
        lines = f.read().splitlines()
    try:
        return json.loads(lines[-1]) if lines else {}
    except ValueError:  # a trace cut off mid-line by a killed run
        return {}


def _method_list(rows: list[TrialRow], registered: dict[str, tuple[str, dict]]) -> list[MethodInfo]:
    """One MethodInfo per config hash in the rows, named and ordered base, random, value, seal (then
    in the paper's column order, so the twin before the reasoning VLA, then by family and K). A
    configuration the store never registered keeps its stored label."""
    vlas = shipped_vlas()
    configs: dict[str, tuple[str, dict, bool]] = {}
    for r in rows:
        if r.config_hash not in configs:
            spec_label, config = registered.get(r.config_hash, (r.method, {"method": r.method.split("[")[0]}))
            configs[r.config_hash] = (spec_label, config, r.config_hash in registered)
    names = unique_names({h: display_name(c, vlas) if known else s for h, (s, c, known) in configs.items()},
                         {h: h[:6] for h in configs})
    families = _families(configs, vlas)
    out = [MethodInfo(h, names[h], c, s, families[h], paper_method_for(c, vlas)) for h, (s, c, _) in configs.items()]

    def order(m: MethodInfo):
        rank = METHOD_ORDER.index(m.method) if m.method in METHOD_ORDER else len(METHOD_ORDER)
        paper_rank = PAPER_ORDER.index(m.paper_method) if m.paper_method in PAPER_ORDER else len(PAPER_ORDER)
        return (rank, paper_rank, m.family, m.k, m.label)

    return sorted(out, key=order)


def _names(m: MethodInfo, item: str) -> bool:
    """Whether a `--methods` item names this configuration (see `ReportData`)."""
    item = item.strip()
    return (m.label.lower() == item.lower() or item in m.spec_label
            or (len(item) >= 4 and m.config_hash.startswith(item)))


def unique_names(names: dict[str, str], tags: dict[str, str]) -> dict[str, str]:
    """Names that two keys share get the key's tag appended (``name#tag``): columns stay distinct."""
    counts = Counter(names.values())
    return {key: name if counts[name] == 1 else f"{name}#{tags[key]}" for key, name in names.items()}


def _families(configs: dict[str, tuple[str, dict, bool]], vlas) -> dict[str, str]:
    """config hash -> its name without K: configurations that differ only in K share it, any two
    that differ in more never do."""
    family_of, name_of = {}, {}
    for h, (stored, config, known) in configs.items():
        if known:
            rest = {k: v for k, v in config.items() if k != "k"}
            family = hashlib.sha1(json.dumps(rest, sort_keys=True).encode()).hexdigest()[:10]
            name_of[family] = display_name(rest, vlas)
        else:  # only the stored label is known: drop its k=N item
            name, _, settings = stored.partition("[")
            extra = [item for item in settings.rstrip("]").split(",") if item and not re.fullmatch(r"k=\d+", item)]
            family = name + (f"[{','.join(extra)}]" if extra else "")
            name_of[family] = family
        family_of[h] = family
    unique = unique_names(name_of, {f: f[:6] for f in name_of})
    return {h: unique[f] for h, f in family_of.items()}


def _instructions() -> dict[tuple[str, int], str]:
    text = (resources.files("seal") / "data" / "instructions.csv").read_text()
    return {(rec["suite"], int(rec["task_id"])): rec["instruction"] for rec in csv.DictReader(text.splitlines())}
