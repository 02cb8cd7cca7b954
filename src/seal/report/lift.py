"""SEAL's lift compared across suites and across verifiers.

Three questions the generalization tables exist to answer, each one table:

- Is SEAL's lift out of distribution larger or smaller than in distribution? Per SEAL configuration
  and suite: SEAL minus its own base on the same trials, and that lift divided by the same pair's
  lift on LIBERO-10.
- Does a method keep its success when one thing changes and the start does not? Lang-Rephrase and
  Lang-Object-Property (the words) and Visual-Viewpoint (the view) keep LIBERO-10's problem files and
  init states, so a trial there and the LIBERO-10 trial with the same task and init state differ in that
  one thing (and the sampling seed, which `seal eval` derives from the suite): their success is paired
  start by start.
- How much of the oracle's lift does a verifier one can deploy keep? For a SEAL configuration with
  a verifier other than the oracle, and the same configuration with the oracle, on the trials all
  three (it, the oracle's, their shared base) ran: (verifier - base) / (oracle - base), with a
  bootstrap interval over those trials.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from seal.errors import InvalidInput
from seal.report.data import MethodInfo, ReportData, succeeded
from seal.report.paper_layout import VERIFIER_KEYS, PaperLayout, base_of
from seal.report.stats import PairedDifference, paired_difference
from seal.report.tables import Table, num, to_csv

IN_DISTRIBUTION = "libero_10"
BOOTSTRAP_DRAWS = 2000


@dataclass
class LiftRow:
    suite: str
    seal: MethodInfo
    base: MethodInfo
    lift: PairedDifference
    in_distribution: PairedDifference | None  # the same pair on LIBERO-10 (None: not run there, or this is it)

    @property
    def ratio(self) -> float | None:
        """This suite's lift over LIBERO-10's (None when LIBERO-10's lift is missing or not positive)."""
        ref = self.in_distribution
        if ref is None or not ref.diff > 0:
            return None
        return self.lift.diff / ref.diff


def lift_rows(layouts: list[PaperLayout]) -> list[LiftRow]:
    """The suite-level SEAL-minus-base differences the paper layouts already hold (their "average"
    rows), each beside the same pair's difference on LIBERO-10."""
    reference = {(d.seal.config_hash, d.base.config_hash): d.by_key["average"]
                 for layout in layouts if layout.suite == IN_DISTRIBUTION for d in layout.differences}
    return [LiftRow(layout.suite, d.seal, d.base, d.by_key["average"],
                    None if layout.suite == IN_DISTRIBUTION else reference.get((d.seal.config_hash, d.base.config_hash)))
            for layout in layouts for d in layout.differences if d.by_key["average"].n]


def lift_display(rows: list[LiftRow]) -> Table:
    headers = ["Suite", "SEAL", "base", "paired trials", "lift (pp)", "95% CI (pp)", "÷ LIBERO-10 lift", "vs LIBERO-10"]
    body = []
    for r in rows:
        ratio = r.ratio
        if r.suite == IN_DISTRIBUTION:
            verdict = "(reference)"
        elif ratio is None:
            verdict = "n/a"
        else:
            verdict = "larger" if ratio > 1 else "smaller" if ratio < 1 else "equal"
        body.append([r.suite, r.seal.label, r.base.label, str(r.lift.n), f"{100 * r.lift.diff:+.1f}",
                     f"[{100 * r.lift.ci[0]:+.1f}, {100 * r.lift.ci[1]:+.1f}]",
                     "" if ratio is None else f"{ratio:.2f}x", verdict])
    notes = ["Lift: SEAL's success minus its base's on the same (task, trial) starts and seeds, with Newcombe's "
             "paired interval. The ratio divides it by the same pair's lift on LIBERO-10 (n/a where LIBERO-10's lift "
             "is not positive or was not run). A ratio from a few trials per task is a point estimate: read it "
             "with both intervals."]
    return Table("SEAL's lift by suite", headers, body, set(), notes, left=3)


def lift_csv(rows: list[LiftRow]) -> str:
    return to_csv(["suite", "seal", "base", "seal_config_hash", "base_config_hash", "paired_trials", "lift_pp",
                   "ci_low_pp", "ci_high_pp", "libero_10_lift_pp", "ratio"],
                  [[r.suite, r.seal.label, r.base.label, r.seal.config_hash, r.base.config_hash, r.lift.n,
                    num(100 * r.lift.diff), num(100 * r.lift.ci[0]), num(100 * r.lift.ci[1]),
                    "" if r.in_distribution is None else num(100 * r.in_distribution.diff),
                    "" if r.ratio is None else num(r.ratio, 3)] for r in rows])


# ---- the same starts, one thing changed -----------------------------------------------------------
@cache
def same_start_change(suite: str, task: int) -> str | None:
    """What a derived suite's task changes while keeping its LIBERO-10 task's problem file and init states
    ("words": the instruction; "view": the background and camera), or None where the starts differ
    (another scene, another goal) or the suite is LIBERO-10 itself."""
    from seal.sim.suites import get_task

    if suite == IN_DISTRIBUTION:
        return None
    try:
        spec, base = get_task(suite, task), get_task(IN_DISTRIBUTION, task)
    except InvalidInput:
        return None
    if (spec.base_key != base.key or spec.bddl_path != base.bddl_path
            or spec.init_states_path != base.init_states_path):
        return None
    changed = [what for what, differs in (("words", spec.instruction != base.instruction),
                                          ("view", (spec.background, spec.camera) != (base.background, base.camera)))
               if differs]
    return " and ".join(changed) or None


@dataclass
class SameStartRow:
    suite: str
    method: MethodInfo
    change: str  # what differs from LIBERO-10 on these starts
    diff: PairedDifference  # this suite's success minus LIBERO-10's, on the same starts

    @property
    def rates(self) -> tuple[float, float]:
        d = self.diff
        return (d.both + d.only_a) / d.n, (d.both + d.only_b) / d.n

    @property
    def ratio(self) -> float | None:
        ood, ind = self.rates
        return ood / ind if ind > 0 else None


def same_start_rows(data: ReportData) -> list[SameStartRow]:
    """Per derived suite whose tasks keep LIBERO-10's starts, and per method configuration that also ran
    LIBERO-10: success on the starts both ran (same task and init state), paired."""
    reference = {(r.config_hash, r.task, r.init_index): succeeded(r)
                 for r in data.rows if r.suite == IN_DISTRIBUTION}
    out = []
    for suite in data.suites:
        changes = {same_start_change(suite, t) for t in data.tasks(suite)}
        if len(changes) != 1 or None in changes:  # some task's starts differ, or tasks change different things
            continue
        (change,) = changes
        for m in data.methods_in(suite):
            pairs = [(succeeded(r), reference[key]) for r in data.rows
                     if r.suite == suite and r.config_hash == m.config_hash
                     and (key := (r.config_hash, r.task, r.init_index)) in reference]
            if pairs:
                out.append(SameStartRow(suite, m, change, paired_difference(pairs)))
    return out


def same_start_display(rows: list[SameStartRow]) -> Table:
    headers = ["Suite", "what differs", "Method", "paired starts", "success here", "on LIBERO-10", "difference (pp)",
               "95% CI (pp)", "÷ LIBERO-10"]
    body = []
    for r in rows:
        ood, ind = r.rates
        ratio = r.ratio
        body.append([r.suite, r.change, r.method.label, str(r.diff.n), f"{100 * ood:.1f}", f"{100 * ind:.1f}",
                     f"{100 * r.diff.diff:+.1f}", f"[{100 * r.diff.ci[0]:+.1f}, {100 * r.diff.ci[1]:+.1f}]",
                     "" if ratio is None else f"{ratio:.2f}x"])
    notes = ["Suites whose tasks keep LIBERO-10's problem files and init states (Lang-Rephrase and "
             "Lang-Object-Property change the instruction's words, Visual-Viewpoint the background and camera): each "
             "trial is paired with the same method's LIBERO-10 trial of the same task and init state, so only that "
             "one thing differs (and the policy's sampling seed, which is drawn per suite). Difference: success here "
             "minus on LIBERO-10, Newcombe's paired interval; the ratio divides the two success rates (blank where "
             "LIBERO-10's is 0)."]
    return Table("The same starts, one thing changed", headers, body, set(), notes, left=3)


def same_start_csv(rows: list[SameStartRow]) -> str:
    return to_csv(["suite", "what_differs", "method", "config_hash", "paired_starts", "success_here",
                   "success_libero_10", "diff_pp", "ci_low_pp", "ci_high_pp", "ratio"],
                  [[r.suite, r.change, r.method.label, r.method.config_hash, r.diff.n, num(r.rates[0], 3),
                    num(r.rates[1], 3), num(100 * r.diff.diff), num(100 * r.diff.ci[0]), num(100 * r.diff.ci[1]),
                    "" if r.ratio is None else num(r.ratio, 3)] for r in rows])


# ---- a deployable verifier's share of the oracle's lift ----------------------------------------
@dataclass
class ShareRow:
    suite: str  # or "all"
    verifier: MethodInfo  # SEAL with the verifier under test
    oracle: MethodInfo  # the same SEAL configuration with the oracle
    base: MethodInfo
    trials: int  # trials all three ran
    rates: tuple[float, float, float]  # success of verifier, oracle, base on those trials
    share: float | None  # (verifier - base) / (oracle - base); None when the oracle lifts nothing
    ci: tuple[float, float] | None  # bootstrap 95% interval of the share over trials


def oracle_twins(seal: MethodInfo, methods: list[MethodInfo]) -> list[MethodInfo]:
    """The same SEAL configuration with the oracle verifier: one per oracle setting the report has (the
    pick check, `grasp`), none if ``seal`` already uses the oracle."""
    if seal.method != "seal" or str(seal.config.get("verifier", "oracle")) == "oracle":
        return []
    def rest(config: dict) -> dict:
        return {k: v for k, v in config.items() if k not in VERIFIER_KEYS}

    def exact_oracle(config: dict) -> bool:  # the oracle without injected errors
        return (str(config.get("verifier", "oracle")) == "oracle" and not config.get("model")
                and not config.get("false_positive") and not config.get("false_negative"))

    return [m for m in methods if m.method == "seal" and exact_oracle(m.config) and rest(m.config) == rest(seal.config)]


def share_of_lift(outcomes: np.ndarray, *, draws: int = BOOTSTRAP_DRAWS, seed: int = 0):
    """``outcomes``: (n, 3) booleans (verifier, oracle, base) per trial. Returns (share, 95% interval);
    the share is None when the oracle's lift is not positive, the interval None when fewer than
    half the bootstrap draws have a positive oracle lift."""
    x = np.asarray(outcomes, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) == 0:
        raise ValueError("outcomes must be an (n, 3) array of (verifier, oracle, base) successes")
    v, o, b = x.mean(0)
    share = (v - b) / (o - b) if o - b > 0 else None
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, len(x), (draws, len(x)))].mean(1)  # (draws, 3)
    gain = means[:, 1] - means[:, 2]
    ok = gain > 0
    if ok.sum() < draws / 2:
        return share, None
    shares = (means[ok, 0] - means[ok, 2]) / gain[ok]
    return share, (float(np.quantile(shares, 0.025)), float(np.quantile(shares, 0.975)))


def share_rows(data: ReportData) -> list[ShareRow]:
    out = []
    for seal in data.methods:
        base = base_of(seal, data.methods)
        oracles = oracle_twins(seal, data.methods) if base is not None else []
        for oracle, suite in ((o, s) for o in oracles for s in [*data.suites, None]):
            triples = data.outcomes([seal.config_hash, oracle.config_hash, base.config_hash], suite)
            if not triples:
                continue
            x = np.array(triples, dtype=bool)
            share, ci = share_of_lift(x)
            rates = tuple(float(r) for r in x.mean(0))
            out.append(ShareRow(suite or "all", seal, oracle, base, len(x), rates, share, ci))
    if len(data.suites) == 1:
        out = [r for r in out if r.suite != "all"]
    return out


def share_display(rows: list[ShareRow]) -> Table:
    headers = ["Suite", "SEAL", "with the oracle", "base", "trials", "SEAL success", "oracle success", "base success",
               "share of the oracle's lift", "95% CI"]
    body = []
    for r in rows:
        body.append([r.suite, r.verifier.label, r.oracle.label, r.base.label, str(r.trials),
                     *(f"{100 * p:.1f}%" for p in r.rates),
                     "n/a" if r.share is None else f"{r.share:.2f}x",
                     "" if r.ci is None else f"[{r.ci[0]:.2f}, {r.ci[1]:.2f}]"])
    notes = ["On the trials all three configurations ran (the same starts and seeds): (SEAL with this verifier - "
             f"base) / (SEAL with the oracle - base). CI: percentile bootstrap over those trials ({BOOTSTRAP_DRAWS} "
             "draws, draws where the oracle lifts nothing left out); n/a where the oracle's lift is not positive."]
    return Table("A verifier's share of the oracle's lift", headers, body, set(), notes, left=4)


def share_csv(rows: list[ShareRow]) -> str:
    return to_csv(["suite", "seal", "oracle", "base", "seal_config_hash", "oracle_config_hash", "base_config_hash",
                   "trials", "seal_rate", "oracle_rate", "base_rate", "share", "ci_low", "ci_high"],
                  [[r.suite, r.verifier.label, r.oracle.label, r.base.label, r.verifier.config_hash,
                    r.oracle.config_hash, r.base.config_hash, r.trials, *(num(p, 4) for p in r.rates),
                    "" if r.share is None else num(r.share, 3), "" if r.ci is None else num(r.ci[0], 3),
                    "" if r.ci is None else num(r.ci[1], 3)] for r in rows])
