"""`seal report`'s method names and the paper's Table VII/VIII layout.

Names: the methods of the generalization tables read as a person would write them, settings that
differ from the usual are said briefly, and two configurations never share a column name. Layout:
a tiny results store (written with the real ResultStore, no simulator) renders the Table VII and
VIII sections with the paper's figures beside ours and a SEAL-minus-base difference that can be
checked by hand.
"""

from __future__ import annotations

import csv
import hashlib
import json
import re

import pytest

from seal.eval.store import ResultStore, TrialRow
from seal.report import write_report
from seal.report.data import ReportData
from seal.report.labels import DEFAULTS, KnownVLA, display_name, shipped_verifier, shipped_vlas
from seal.report.paper import paper_method_for
from seal.report.stats import paired_from_counts
from seal.steer.method import MethodSpec, settings
from seal.verify.options import OracleOptions

HEX = re.compile(r"[0-9a-f]{6,}")
VALUE_DIGEST = "0123456789ab"  # a stand-in for a checkpoint digest
LEARNED_DIGEST = shipped_verifier()  # rows of "the learned verifier" are the shipped one's


def _config_hash(config: dict) -> str:
    return hashlib.sha1(json.dumps(config, sort_keys=True).encode()).hexdigest()[:10]


def _standard() -> dict[str, dict]:
    """The issue's five methods, as canonical configs: built with MethodSpec where no trained
    checkpoint beyond the shipped VLAs is needed, else derived from those (V-GPS and learned
    verifier weights named by a digest, as a store holds them)."""
    twin = MethodSpec(method="base", policy="vla:twin").canonical()
    reason = MethodSpec(method="base", policy="vla").canonical()
    oracle = MethodSpec(method="seal", policy="vla").canonical()
    vgps = {**twin, "method": "value", "k": 10, "value_ckpt": VALUE_DIGEST, "value_goal": "task"}
    learned = {**oracle, "verifier": "learned", "model": LEARNED_DIGEST}
    return {"twin (pi0)": twin, "twin + V-GPS": vgps, "reasoning VLA": reason,
            "reasoning VLA + SEAL (oracle)": oracle, "reasoning VLA + SEAL (learned verifier)": learned}


# ---- names ----------------------------------------------------------------------------------------
def test_defaults_agree_with_method_spec():
    spec = MethodSpec()  # render is resolved at construction: the scripted expert's is stock
    assert {k: getattr(spec, k) for k in DEFAULTS} == DEFAULTS
    assert set(DEFAULTS) <= {s.name for s in settings()}  # the loop's and every plug-in's settings


def test_standard_methods_read_as_a_person_would_write_them():
    for name, config in _standard().items():
        got = display_name(config)
        assert got == name
        assert not any(ch in got for ch in "[]=") and not HEX.search(got), got
    assert display_name(MethodSpec(method="base").canonical()) == "scripted expert"
    # the expert before it read Held (every stored scripted-expert row): its own name
    assert display_name(MethodSpec(method="base", grip="pads").canonical()) == "scripted expert (pad-contact grip)"
    assert display_name(MethodSpec(method="seal").canonical()) == "scripted expert + SEAL (oracle)"
    # rows stored before the oracle's Held check ran with the pad check: their name says so
    pads = MethodSpec(method="seal", policy="vla", verifier_options=OracleOptions(grasp="pads")).canonical()
    assert "grasp" not in pads and display_name(pads) == "reasoning VLA + SEAL (oracle, pad-contact picks)"
    # and before repeated sub-plans were placed after the done list's latest item, by counting done items
    counted = MethodSpec(method="seal", policy="vla", subplan_ref="count").canonical()
    assert "subplan_ref" not in counted and display_name(counted) == "reasoning VLA + SEAL (oracle, repeats by count)"
    assert display_name(MethodSpec(method="random").canonical()) == "scripted expert + random pick"


def test_the_earlier_shipped_verifier_keeps_a_name_of_its_own():
    # rows made with the first shipped learned verifier must not read as the current one's
    current = MethodSpec(policy="vla", verifier="learned").canonical()
    earlier = MethodSpec(policy="vla", verifier="learned:expert").canonical()
    assert current["model"] != earlier["model"]
    assert display_name(current) == "reasoning VLA + SEAL (learned verifier)"
    assert display_name(earlier) == "reasoning VLA + SEAL (learned verifier from expert rounds)"
    second = MethodSpec(policy="vla", verifier="learned:vla_rounds").canonical()
    assert len({current["model"], earlier["model"], second["model"]}) == 3
    assert display_name(second) == "reasoning VLA + SEAL (learned verifier from the first VLA's rounds)"
    third = MethodSpec(policy="vla", verifier="learned:dagger_rounds").canonical()
    assert len({current["model"], earlier["model"], second["model"], third["model"]}) == 4
    assert display_name(third) == "reasoning VLA + SEAL (learned verifier from the DAgger rounds)"
    fourth = MethodSpec(policy="vla", verifier="learned:pad_labels").canonical()
    assert len({current["model"], earlier["model"], second["model"], third["model"], fourth["model"]}) == 5
    assert display_name(fourth) == "reasoning VLA + SEAL (learned verifier from pad-check labels)"
    fifth = MethodSpec(policy="vla", verifier="learned:held_labels").canonical()  # named by its manifest's label
    assert len({current["model"], earlier["model"], second["model"], third["model"], fourth["model"],
                fifth["model"]}) == 6
    assert display_name(fifth) == "reasoning VLA + SEAL (learned verifier from the round-2 VLA's rounds)"
    # a run that never shipped is named by its digest, never as the shipped one
    run = {**current, "model": "910132eefae3", "threshold": 0.8}
    assert display_name(run) == "reasoning VLA + SEAL (learned verifier 910132eefae3, threshold 0.8)"


def test_a_stricter_verifier_threshold_is_a_method_of_its_own_and_says_so():
    from seal.errors import InvalidInput
    from seal.steer.method import parse_methods
    from seal.verify import verifier_for

    plain, strict = parse_methods("seal:policy=vla:verifier=learned,seal:policy=vla:verifier=learned:threshold=0.8")
    # the default leaves every stored configuration's hash as it was; a threshold makes a new one
    assert "threshold" not in plain.canonical() and strict.canonical()["threshold"] == 0.8
    assert plain.config_hash != strict.config_hash
    assert display_name(strict.canonical()) == "reasoning VLA + SEAL (learned verifier, threshold 0.8)"
    assert verifier_for(strict).threshold == 0.8 and verifier_for(plain).threshold == 0.5
    for bad, message in (("verifier=learned:threshold=1.5", "probability in \\[0, 1\\]"),
                         ("threshold=0.5", "for the learned verifier, not 'oracle'")):
        with pytest.raises(InvalidInput, match=message):
            parse_methods(f"seal:policy=vla:{bad}")


def test_the_paper_column_follows_the_policy():
    expected = {"twin (pi0)": "pi0", "twin + V-GPS": "pi0_vgps", "reasoning VLA": "pi0_reason",
                "reasoning VLA + SEAL (oracle)": "seal", "reasoning VLA + SEAL (learned verifier)": "seal"}
    assert {name: paper_method_for(config) for name, config in _standard().items()} == expected
    # a twin kept under another name when a retrained one shipped still stands where pi0 stands
    kept = {"abc123abc123": KnownVLA("twin, round 0", "fast", twin=True)}
    config = {"method": "base", "policy": "vla", "mode": "sync", "render": "fast", "policy_ckpt": "abc123abc123"}
    assert paper_method_for(config, kept) == "pi0" and display_name(config, vlas=kept) == "twin, round 0 (pi0)"


def test_settings_that_differ_are_named_briefly():
    assert display_name(MethodSpec(method="seal", k=4).canonical()) == "scripted expert + SEAL (oracle, K=4)"
    assert display_name(MethodSpec(method="seal", policy="vla", pick="best", render="stock", rounds=3).canonical()) \
        == "reasoning VLA + SEAL (oracle, 3 rounds, best pick, stock render)"
    noisy = MethodSpec(method="seal", verifier="noisy", false_positive=0.1, knobs="clean").canonical()
    assert display_name(noisy) == "clean scripted expert + SEAL (noisy oracle, false passes 10%)"
    assert display_name(MethodSpec(method="base", policy="vla:twin", render="stock").canonical()) == \
        "twin (pi0, stock render)"
    assert display_name(MethodSpec(method="base", policy="vla", noise_scale=0.0).canonical()) == \
        "reasoning VLA (flow noise x0)"
    # A VLA the report does not know is named by its weights, and says its render (its usual one is unknown).
    other = {**MethodSpec(method="base", policy="vla").canonical(), "policy_ckpt": "a1b2c3d4e5f6"}
    assert display_name(other, vlas={}) == "VLA checkpoint a1b2c3 (fast render)"
    # A setting this version does not know still shows, so configurations stay apart.
    assert display_name({**MethodSpec(method="seal").canonical(), "new_knob": 3}) == \
        "scripted expert + SEAL (oracle, new_knob=3)"


def test_shipped_checkpoints_are_known_by_their_digests():
    known = shipped_vlas()
    twin = MethodSpec(method="base", policy="vla:twin").canonical()["policy_ckpt"]
    reason = MethodSpec(method="base", policy="vla").canonical()["policy_ckpt"]
    assert known[twin].name == "twin" and known[reason].name == "reasoning VLA"
    assert display_name(MethodSpec(method="base", policy="vla").canonical(),
                        vlas={reason: KnownVLA("my VLA", "fast")}) == "my VLA"


def test_shipped_q_functions_other_than_the_default_are_named():
    """The V-GPS rows made with the first shipped Q-function must not read as the default's."""
    twin = MethodSpec(method="base", policy="vla:twin").canonical()
    demos = {**twin, "method": "value", "k": 10, "value_ckpt": "a353a1507bf5", "value_goal": "task"}  # l10_demos
    assert display_name(demos) == "twin + V-GPS (Q from demonstrations only)"
    assert display_name({**demos, "value_ckpt": "257c70543923"}) == "twin + V-GPS"  # the default, l10_twin_rollouts
    assert display_name({**demos, "value_ckpt": "ba9876543210"}) == "twin + V-GPS"  # a run of one's own


def test_distinct_configs_keep_distinct_names(tmp_path):
    configs = list(_standard().values())
    configs += [MethodSpec(method="seal", policy="vla", k=k).canonical() for k in (2, 4)]
    configs.append({**configs[1], "value_ckpt": "ba9876543210"})  # a second V-GPS: same words, other weights
    db = tmp_path / "names.db"
    with ResultStore(db) as store:
        for config in configs:
            h = _config_hash(config)
            store.register_method(h, config["method"], config)
            store.add(TrialRow(method=config["method"], config_hash=h, suite="libero_10", task=0, trial=0,
                               init_index=0, seed=0))
    methods = ReportData(db).methods
    labels = [m.label for m in methods]
    assert len(set(labels)) == len(configs)
    vgps = sorted(label for label in labels if label.startswith("twin + V-GPS"))
    assert len(vgps) == 2 and all(re.fullmatch(r"twin \+ V-GPS#[0-9a-f]{6}", v) for v in vgps)
    assert "reasoning VLA + SEAL (oracle, K=2)" in labels and "reasoning VLA + SEAL (oracle)" in labels
    assert set(_standard()) - {"twin + V-GPS"} <= set(labels)  # the others kept their plain names
    # Runtime-vs-K lines join the configurations that differ only in K.
    oracle = [m for m in methods if m.label.startswith("reasoning VLA + SEAL (oracle")]
    assert len(oracle) == 3 and {m.family for m in oracle} == {"reasoning VLA + SEAL (oracle)"}
    assert len({m.family for m in methods}) == len(methods) - 2


# ---- Table VII / VIII layout ------------------------------------------------------------------------
TRIALS = 3
# Successful trials per (suite, task, method name): trial t succeeds if t is listed.
WINS = {
    ("lang_rephrase", 0): {"twin (pi0)": [0], "twin + V-GPS": [], "reasoning VLA": [0],
                           "reasoning VLA + SEAL (oracle)": [0, 1, 2], "reasoning VLA + SEAL (learned verifier)": [1]},
    ("lang_rephrase", 1): {"twin (pi0)": [], "twin + V-GPS": [2], "reasoning VLA": [],
                           "reasoning VLA + SEAL (oracle)": [1], "reasoning VLA + SEAL (learned verifier)": []},
    ("composition", 3): {"twin (pi0)": [], "twin + V-GPS": [], "reasoning VLA": [2],
                         "reasoning VLA + SEAL (oracle)": [0, 2], "reasoning VLA + SEAL (learned verifier)": [0]},
}
ORACLE = "reasoning VLA + SEAL (oracle)"
LEARNED = "reasoning VLA + SEAL (learned verifier)"


@pytest.fixture(scope="module")
def layout_report(tmp_path_factory):
    root = tmp_path_factory.mktemp("layout")
    db = root / "ood.db"
    configs = _standard()
    with ResultStore(db) as store:
        for config in configs.values():
            store.register_method(_config_hash(config), config["method"], config)
        for (suite, task), wins in WINS.items():
            for name, won in wins.items():
                for t in range(TRIALS):
                    store.add(TrialRow(method=configs[name]["method"], config_hash=_config_hash(configs[name]),
                                       suite=suite, task=task, trial=t, init_index=t, seed=100 + t, success=t in won,
                                       steps=50, wall_s=1.0))
    return write_report(db, root / "report", episodes=False)


def _md_table(md: str, title: str) -> list[list[str]]:
    block = md.split(f"### {title}")[1].split("\n\n")[1]
    return [[c.strip() for c in line.strip().strip("|").split(" | ")] for line in block.splitlines()]


def _diff(both: int, seal_only: int, base_only: int, neither: int) -> str:
    d = paired_from_counts(both, seal_only, base_only, neither)
    return f"{100 * d.diff:+.1f} [{100 * d.ci[0]:+.1f}, {100 * d.ci[1]:+.1f}]"


def test_table_vii_layout_renders_beside_the_paper(layout_report):
    md = layout_report.markdown.read_text()
    assert "## Table VII layout: out-of-distribution suites" in md
    assert "## Table VIII layout: behavior composition" in md
    assert "Table II layout" not in md  # the store holds no LIBERO-10 rows
    rows = _md_table(md, "lang_rephrase: ours beside the paper (Table VII layout)")
    assert rows[0] == ["Task", "twin (pi0)", "paper π0", "twin + V-GPS", "paper π0+V-GPS", "reasoning VLA",
                       "paper π0-reason", LEARNED, ORACLE, "paper SEAL",
                       f"{LEARNED} − reasoning VLA (pp)", f"{ORACLE} − reasoning VLA (pp)"]
    assert [r[0] for r in rows[2:]] == ["0", "1", "Average"]
    task0, task1, avg = rows[2], rows[3], rows[4]
    # The paper's Table VII, Lang-Rephrase task 0: pi0 86, V-GPS 92, pi0-reason 92, SEAL 98.
    assert [task0[i] for i in (2, 4, 6, 9)] == ["86.0", "92.0", "92.0", "98.0"]
    assert task0[8] == "**100.0 [43.9, 100.0]**"  # 3/3, Wilson, the best of ours in the row
    assert task0[5] == "33.3 [6.1, 79.2]"
    # SEAL (oracle) - base on task 0: base wins trial 0, SEAL all three -> 1 both, 2 SEAL only: +66.7 pp.
    assert task0[11] == _diff(1, 2, 0, 0) and task0[11].startswith("+66.7 [")
    # Task 1: SEAL wins trial 1 only -> +33.3; the suite (Average row) pools the six pairs: +50.0.
    assert task1[11] == _diff(0, 1, 0, 2) and task1[11].startswith("+33.3")
    assert avg[11].strip("*") == _diff(1, 3, 0, 2) and avg[11].strip("*").startswith("+50.0")
    # Learned verifier - base on task 0: base wins trial 0, learned trial 1 -> one each way: +0.0.
    assert task0[10] == _diff(0, 1, 1, 1) and task0[10].startswith("+0.0")
    # Paper average over the tasks shown: SEAL (98 + 100) / 2.
    assert avg[9] == "99.0"


def test_table_viii_layout_and_its_csv(layout_report):
    md = layout_report.markdown.read_text()
    rows = _md_table(md, "composition: ours beside the paper (Table VIII layout)")
    task3 = rows[2]
    # The paper's Table VIII (LIBERO-100), task 3: pi0 14, V-GPS 18, pi0-reason 2, SEAL 4.
    assert [task3[i] for i in (2, 4, 6, 9)] == ["14.0", "18.0", "2.0", "4.0"]
    # Oracle 0,2 vs base 2 -> both 1 (trial 2), SEAL only 1 (trial 0), neither 1.
    assert task3[11] == _diff(1, 1, 0, 1)
    by_name = {p.name: p for p in layout_report.csv}
    diffs = list(csv.DictReader(by_name["seal_minus_base.csv"].read_text().splitlines()))
    suite_row = next(r for r in diffs
                     if (r["suite"], r["task"], r["seal"]) == ("lang_rephrase", "average", ORACLE))
    assert (suite_row["paired_trials"], suite_row["both"], suite_row["seal_only"], suite_row["base_only"]) == \
        ("6", "1", "3", "0")
    assert float(suite_row["diff_pp"]) == 50.0 and suite_row["base"] == "reasoning VLA"
    assert suite_row["seal_config_hash"] == _config_hash(_standard()[ORACLE])
    # Readable names in the wide CSV's header, the config hash kept in its rows.
    wide = list(csv.DictReader(by_name["success_lang_rephrase.csv"].read_text().splitlines()))
    assert wide[0][f"{ORACLE} config_hash"] == _config_hash(_standard()[ORACLE])
    assert float(wide[0][f"{ORACLE} success_pct"]) == 100.0


def test_the_html_has_the_layout_and_the_names(layout_report):
    index = layout_report.index_html.read_text()
    assert "Table VII layout: out-of-distribution suites" in index
    assert "lang_rephrase: ours beside the paper (Table VII layout)" in index
    assert f"{ORACLE} − reasoning VLA (pp)" in index and "paper π0+V-GPS" in index
    assert "seal[" not in index.split("Method configurations")[0]  # stored labels only in the configurations list


# ---- lift across suites and a verifier's share of the oracle's lift ---------------------------------
LIFT_WINS = {  # (suite, task) -> method -> successful trials of 4
    ("libero_10", 0): {"reasoning VLA": [0], ORACLE: [0, 1, 2, 3], LEARNED: [0, 1, 2]},
    ("libero_10", 1): {"reasoning VLA": [], ORACLE: [1, 2], LEARNED: [1]},
    ("lang_rephrase", 0): {"reasoning VLA": [0], ORACLE: [0, 1], LEARNED: [0]},
    ("lang_rephrase", 1): {"reasoning VLA": [], ORACLE: [], LEARNED: [3]},
}


def test_lift_by_suite_and_the_learned_verifiers_share_of_the_oracles(tmp_path):
    from seal.report.lift import share_of_lift

    configs = _standard()
    db = tmp_path / "lift.db"
    with ResultStore(db) as store:
        for name in ("reasoning VLA", ORACLE, LEARNED):
            store.register_method(_config_hash(configs[name]), configs[name]["method"], configs[name])
        for (suite, task), wins in LIFT_WINS.items():
            for name, won in wins.items():
                for t in range(4):
                    store.add(TrialRow(method=configs[name]["method"], config_hash=_config_hash(configs[name]),
                                       suite=suite, task=task, trial=t, init_index=t, seed=t, success=t in won,
                                       steps=50, wall_s=1.0))
        # the learned verifier at another operating point is still the oracle's SEAL with another
        # verifier: its share is taken against the same oracle rows (here: the same wins, the same share)
        strict = {**configs[LEARNED], "threshold": 0.8}
        store.register_method(_config_hash(strict), strict["method"], strict)
        for (suite, task), wins in LIFT_WINS.items():
            for t in range(4):
                store.add(TrialRow(method=strict["method"], config_hash=_config_hash(strict), suite=suite, task=task,
                                   trial=t, init_index=t, seed=t, success=t in wins[LEARNED], steps=50, wall_s=1.0))
        # the oracle with the pad check for picks (rows stored before the Held check): one more oracle
        # for the learned verifier to be compared with, on LIBERO-10 only, solving one start fewer
        pads = {k: v for k, v in configs[ORACLE].items() if k != "grasp"}
        store.register_method(_config_hash(pads), pads["method"], pads)
        for task in (0, 1):
            for t in range(4):
                won = t in LIFT_WINS["libero_10", task][ORACLE] and (task, t) != (1, max(LIFT_WINS["libero_10", 1][ORACLE]))
                store.add(TrialRow(method=pads["method"], config_hash=_config_hash(pads), suite="libero_10", task=task,
                                   trial=t, init_index=t, seed=t, success=won, steps=50, wall_s=1.0))
    report = write_report(db, tmp_path / "report", episodes=False)
    by_name = {p.name: p for p in report.csv}
    rows = list(csv.DictReader(by_name["share_of_oracle_lift.csv"].read_text().splitlines()))
    at_80 = {r["suite"]: r for r in rows if r["seal_config_hash"] == _config_hash(strict) and r["oracle"] == ORACLE}
    assert float(at_80["libero_10"]["share"]) == 0.6 and at_80["libero_10"]["oracle"] == ORACLE
    lifts = {(r["suite"], r["seal"]): r for r in csv.DictReader(by_name["lift_by_suite.csv"].read_text().splitlines())}
    # Oracle: LIBERO-10 6/8 vs 1/8 -> +62.5 pp; Lang-Rephrase 2/8 vs 1/8 -> +12.5 pp, 0.2x of LIBERO-10's.
    assert float(lifts["libero_10", ORACLE]["lift_pp"]) == 62.5 and lifts["libero_10", ORACLE]["ratio"] == ""
    assert float(lifts["lang_rephrase", ORACLE]["lift_pp"]) == 12.5
    assert float(lifts["lang_rephrase", ORACLE]["ratio"]) == 0.2
    # the threshold is the verifier's, not the policy's: the strict configuration has the same base
    assert float(lifts["libero_10", "reasoning VLA + SEAL (learned verifier, threshold 0.8)"]["lift_pp"]) == 37.5
    md = report.markdown.read_text()
    row = next(r for r in _md_table(md, "SEAL's lift by suite") if r[:2] == ["lang_rephrase", ORACLE])
    assert row[-2:] == ["0.20x", "smaller"]
    # Learned verifier: LIBERO-10 4/8 -> (4 - 1) / (6 - 1) = 0.6 of the oracle's lift; Lang-Rephrase
    # 2/8 -> (2 - 1) / (2 - 1) = 1.0; both suites pooled: (6 - 2) / (8 - 2).
    shares = {r["suite"]: r for r in rows if r["seal"] == LEARNED and r["oracle"] == ORACLE}
    # against each oracle the store has, its own row: with the pad-check oracle (5/8), (4 - 1) / (5 - 1)
    padded = {r["suite"]: r for r in rows if r["seal"] == LEARNED and r["oracle"] == f"{ORACLE[:-1]}, pad-contact picks)"}
    assert set(padded) == {"libero_10", "all"} and float(padded["libero_10"]["share"]) == 0.75
    assert float(shares["libero_10"]["share"]) == 0.6 and float(shares["lang_rephrase"]["share"]) == 1.0
    assert abs(float(shares["all"]["share"]) - 4 / 6) < 1e-3 and shares["all"]["trials"] == "16"
    assert float(shares["libero_10"]["ci_low"]) <= 0.6 <= float(shares["libero_10"]["ci_high"])
    assert "A verifier's share of the oracle's lift" in md
    # The same starts, one thing changed: Lang-Rephrase's trial (task, t) against LIBERO-10's, per method.
    # Oracle: both on 2 starts, LIBERO-10 only on 4 -> 25% vs 75%, -50 pp, 0.33x; the learned verifier
    # solves one start only in other words (task 1, trial 3) -> 25% vs 50%, 0.5x.
    same = {r["method"]: r for r in csv.DictReader(by_name["same_starts.csv"].read_text().splitlines())}
    assert {(r["suite"], r["what_differs"]) for r in same.values()} == {("lang_rephrase", "words")}
    oracle = same[ORACLE]
    assert (oracle["paired_starts"], oracle["success_here"], oracle["success_libero_10"]) == ("8", "0.25", "0.75")
    assert float(oracle["diff_pp"]) == -50.0 and float(oracle["ratio"]) == 0.333
    assert float(oracle["ci_low_pp"]) < -50.0 < float(oracle["ci_high_pp"]) < 0
    assert float(same[LEARNED]["ratio"]) == 0.5 and float(same[LEARNED]["diff_pp"]) == -25.0
    assert "The same starts, one thing changed" in md
    # which suites keep LIBERO-10's starts is read from their task specs: the view suite does, the scene edits
    # and the new goals do not
    from seal.report.lift import same_start_change

    assert [same_start_change(s, 3) for s in ("lang_object_property", "visual_viewpoint", "visual_scene",
                                              "composition", "libero_10")] == ["words", "view", None, None, None]
    # the bootstrap: a verifier that always agrees with the oracle keeps all of its lift, exactly
    x = [(o, o, b) for o, b in [(1, 0)] * 6 + [(1, 1)] * 2 + [(0, 0)] * 4]
    assert share_of_lift(x) == (1.0, (1.0, 1.0))
    # no lift from the oracle: no share
    assert share_of_lift([(1, 0, 0), (0, 0, 0)])[0] is None
