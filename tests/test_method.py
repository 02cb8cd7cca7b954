"""One method description (`MethodSpec`) for `seal run`, `seal eval` and the benchmarks; the
registries at the seams; the CLI's handling of bad values."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from seal.cli import main
from seal.errors import InvalidInput
from seal.eval.trials import trial_seed
from seal.steer.method import MethodSpec, parse_methods, parse_mismatch

SHORT = 40  # control steps: enough for a sub-plan round with K=2, short enough for a test


# ---- identity ---------------------------------------------------------------------------------
def test_config_hashes_of_older_stores_are_kept():
    """Hashes written by the MethodSpec of eval/trials.py before the fields were added (computed
    with that code): a store made then must find its trials now."""
    # every SEAL result before the declared-completion check ran as done_check="trust", and every scripted-
    # expert result before 2026-12-05 with the pad check, in the oracle (grasp) and in the expert (grip); every
    # SEAL result before 2026-12-05 placed a repeated sub-plan by counting done items (subplan_ref)
    old = dict(done_check="trust", grasp="pads", grip="pads", subplan_ref="count")
    assert MethodSpec(**old).config_hash == "7687d79a15"
    assert MethodSpec(method="base", grip="pads").config_hash == "85d6a51ef6"
    assert MethodSpec(k=5, rounds=1, knobs="clean", **old).config_hash == "d7489a2d17"
    assert MethodSpec().config_hash != MethodSpec(subplan_ref="count").config_hash  # the rule is a new config
    assert MethodSpec(method="base").config_hash == MethodSpec(method="base", subplan_ref="count").config_hash
    assert MethodSpec(method="random", k=4, render="fast", grip="pads").config_hash == "259cb3eb85"
    assert MethodSpec(method="base").config_hash != "85d6a51ef6"  # today's expert reads Held: a new config


SHIPPED_VLA = Path(__file__).resolve().parents[1] / "src/seal/policies/vla/checkpoints"
SHIPPED_VERIFIER = Path(__file__).resolve().parents[1] / "src/seal/verify/checkpoints/learned"
EXPERT_VERIFIER = SHIPPED_VERIFIER.parent / "expert"  # the first shipped one, `learned:expert`
VLA_ROUNDS_VERIFIER = SHIPPED_VERIFIER.parent / "vla_rounds"  # the second, `learned:vla_rounds`
DAGGER_ROUNDS_VERIFIER = SHIPPED_VERIFIER.parent / "dagger_rounds"  # the third, `learned:dagger_rounds`
PAD_LABELS_VERIFIER = SHIPPED_VERIFIER.parent / "pad_labels"  # the fourth, `learned:pad_labels`
HELD_LABELS_VERIFIER = SHIPPED_VERIFIER.parent / "held_labels"  # the fifth, `learned:held_labels`
SHIPPED_VALUES = Path(__file__).resolve().parents[1] / "src/seal/value/checkpoints"  # V-GPS: l10_twin_rollouts default


def _shipped_digests() -> dict:
    """The shipped weights' names, computed here independently of the code under test."""
    import hashlib

    vla = {name: json.loads((SHIPPED_VLA / name / "manifest.json").read_text())["files"]["model.safetensors"]["sha256"][:12]
           for name in ("reason", "twin", "reason_r0", "twin_r0", "reason_r2", "twin_r3")}
    learned = {name: hashlib.sha1((d / "model.safetensors").read_bytes() + (d / "config.json").read_bytes()).hexdigest()[:12]
               for name, d in (("learned", SHIPPED_VERIFIER), ("learned:expert", EXPERT_VERIFIER),
                               ("learned:vla_rounds", VLA_ROUNDS_VERIFIER),
                               ("learned:dagger_rounds", DAGGER_ROUNDS_VERIFIER),
                               ("learned:pad_labels", PAD_LABELS_VERIFIER),
                               ("learned:held_labels", HELD_LABELS_VERIFIER))}
    value = {f"value:{name}": hashlib.sha1((SHIPPED_VALUES / name / "value.safetensors").read_bytes()
                                           + (SHIPPED_VALUES / name / "value.json").read_bytes()).hexdigest()[:12]
             for name in ("l10_demos", "l10_twin_rollouts")}
    return {**vla, **learned, **value}


def _fixed_value_checkpoint(tmp_path: Path) -> Path:
    """A V-GPS checkpoint directory with fixed bytes: only its digest enters a hash, never its weights."""
    from seal.checkpoint import write_manifest

    d = tmp_path / "vgps"
    d.mkdir()
    (d / "value.safetensors").write_bytes(b"not really weights: only their digest is pinned")
    (d / "value.json").write_text('{"image_size": 56}')
    write_manifest(d, kind="seal-vgps", files=["value.safetensors", "value.json"])
    return d


def test_config_hashes_of_plugins_are_kept(tmp_path):
    """Hashes, labels and canonical forms of every plug-in's settings, computed with the code before the
    plug-ins owned their options (issue 35): stores made then must find their trials now."""
    # These pins name the shipped weights of today; a retrained shipped checkpoint is a new method (re-pin then).
    # The first shipped pair stays loadable by name (vla:reason_r0, vla:twin_r0): the pins below name it that
    # way, so stores made with it keep finding their trials after the round-2 VLA and its twin shipped.
    assert _shipped_digests() == {"reason": "4edbeeb3b398", "twin": "9b6a737845d5", "reason_r0": "009dcdd7fb35",
                                  "twin_r0": "14bb7098169e", "reason_r2": "563400068f48", "twin_r3": "cd9f0d7bdb3c",
                                  "learned": "e6ff68f2135b", "learned:held_labels": "3ef801b0d635",
                                  "learned:expert": "8818a7a2714f", "learned:vla_rounds": "808648b1ea87",
                                  "learned:dagger_rounds": "c0646b399509", "learned:pad_labels": "91510e95b336",
                                  "value:l10_demos": "a353a1507bf5", "value:l10_twin_rollouts": "257c70543923"}
    value = _fixed_value_checkpoint(tmp_path)
    # Every oracle result these pins stand for ran with the pad check for picks (grasp="pads", left out
    # of the hash as its legacy value); the oracle's default since 2026-12-05 is Held, a new hash.
    # Every SEAL result among them placed a repeated sub-plan by counting done items (subplan_ref="count", legacy too).
    cases = [  # (spec, config hash, label, canonical form: its keys in this order)
        (MethodSpec(subplan_ref="count", policy="vla:reason_r0", grasp="pads"), "0c35fb9f53", "seal[policy=vla,render=fast,policy_ckpt=009dcdd7fb35,subplan_ref=count,grasp=pads]",
         {"method": "seal", "k": 10, "rounds": 2, "verifier": "oracle", "model": None, "false_positive": 0.0,
          "false_negative": 0.0, "policy": "vla", "mode": "sync", "render": "fast", "policy_ckpt": "009dcdd7fb35",
          "done_check": "verify"}),  # a named checkpoint sits before done_check; the hash does not see the order
        (MethodSpec(method="base", policy="vla:reason_r0"), "767e9bd037", "base[policy=vla,render=fast,policy_ckpt=009dcdd7fb35]",
         {"method": "base", "policy": "vla", "mode": "sync", "render": "fast", "policy_ckpt": "009dcdd7fb35"}),
        (MethodSpec(subplan_ref="count", policy="vla:twin_r0", grasp="pads"), "ea43916c1f", "seal[policy=vla,render=fast,policy_ckpt=14bb7098169e,subplan_ref=count,grasp=pads]", None),
        (MethodSpec(method="base", policy="vla:twin_r0"), "d1fec96036",
         "base[policy=vla,render=fast,policy_ckpt=14bb7098169e]", None),
        (MethodSpec(subplan_ref="count", policy="vla", policy_ckpt="twin_r0", planner="annotations", check_every=40, grasp="pads"), "1dc4345fc4",
         "seal[policy=vla,render=fast,check_every=40,planner=annotations,policy_ckpt=14bb7098169e,subplan_ref=count,grasp=pads]", None),
        # the verifier every table before 2026-12-04 used, by its name and by its directory
        (MethodSpec(subplan_ref="count", verifier="learned:expert", grip="pads"), "df755dab3f", "seal[verifier=learned,model=8818a7a2714f,subplan_ref=count,grip=pads]",
         {"method": "seal", "k": 10, "rounds": 2, "verifier": "learned", "model": "8818a7a2714f", "false_positive": 0.0,
          "false_negative": 0.0, "policy": "scripted", "knobs": "misaligned", "mode": "sync", "render": "stock",
          "done_check": "verify"}),
        (MethodSpec(subplan_ref="count", verifier="learned", model=str(EXPERT_VERIFIER), done_check="trust", grip="pads"), "38151112c4",
         "seal[verifier=learned,model=8818a7a2714f,done_check=trust,subplan_ref=count,grip=pads]", None),
        (MethodSpec(method="value", value_ckpt=str(value), grip="pads"), "34e1da3e4d", "value[ckpt=vgps,grip=pads]",
         {"method": "value", "k": 10, "policy": "scripted", "knobs": "misaligned", "mode": "sync", "render": "stock",
          "value_ckpt": "bd58b24a6834", "value_goal": "task"}),
        (MethodSpec(method="value", value_ckpt=str(value / "value.json"), value_goal="subplan", k=4, grip="pads"), "73938379e0",
         "value[ckpt=value.json,k=4,value_goal=subplan,grip=pads]", None),
        (MethodSpec(subplan_ref="count", policy="remote", planner="annotations", prompt="subplan", grasp="pads"), "531977047c",
         "seal[policy=remote,planner=annotations,prompt=subplan,subplan_ref=count,grasp=pads]",
         {"method": "seal", "k": 10, "rounds": 2, "verifier": "oracle", "model": None, "false_positive": 0.0,
          "false_negative": 0.0, "policy": "remote", "mode": "sync", "render": "stock", "planner": "annotations",
          "prompt": "subplan", "done_check": "verify"}),
        (MethodSpec(subplan_ref="count", policy="remote", planner="vlm", planner_model="gpt-4o", annotations="a.json", prompt="subplan",
                    port=9000, grasp="pads"), "ed1ffc1e9d",
         "seal[policy=remote,planner=vlm,annotations=a.json,planner_model=gpt-4o,prompt=subplan,subplan_ref=count,grasp=pads]", None),
        (MethodSpec(subplan_ref="count", verifier="noisy", false_positive=0.1, false_negative=0.2, grasp="pads", grip="pads"), "0d77a42d98",
         "seal[verifier=noisy,false_positive=0.1,false_negative=0.2,subplan_ref=count,grip=pads,grasp=pads]", None),
        (MethodSpec(subplan_ref="count", mismatch=(1.3, 0.8, 1.2), grasp="pads", grip="pads"), "d741ef288a", "seal[mismatch=1.3/0.8/1.2,subplan_ref=count,grip=pads,grasp=pads]",
         {"method": "seal", "k": 10, "rounds": 2, "verifier": "oracle", "model": None, "false_positive": 0.0,
          "false_negative": 0.0, "policy": "scripted", "knobs": "misaligned", "mode": "sync", "render": "stock",
          "mismatch": [1.3, 0.8, 1.2], "done_check": "verify"}),
        (MethodSpec(subplan_ref="count", done_check="trust", grasp="pads", grip="pads"), "7687d79a15", "seal[done_check=trust,subplan_ref=count,grip=pads,grasp=pads]", None),
        (MethodSpec(subplan_ref="count", k=4, verifier="noisy", false_positive=0.1, mismatch=(1.3, 0.8, 1.2), done_check="trust", pick="best",
                    verify_order="arrival", subplan_budget=120, grasp="pads", grip="pads"), "41e0d352c0",
         "seal[k=4,verifier=noisy,false_positive=0.1,mismatch=1.3/0.8/1.2,subplan_budget=120,pick=best,"
         "verify_order=arrival,done_check=trust,subplan_ref=count,grip=pads,grasp=pads]", None),
        (MethodSpec(method="random", k=3, render="fast", mode="replay", grip="pads"), "551786a35d", "random[k=3,mode=replay,render=fast,grip=pads]",
         None),
    ]
    for spec, config_hash, label, canonical in cases:
        assert (spec.config_hash, spec.label) == (config_hash, label), (spec, spec.canonical())
        if canonical is not None:
            assert list(spec.canonical().items()) == list(canonical.items())
    # the same methods written as `seal eval --methods` items
    (vla, twin, noisy) = parse_methods("seal:policy=vla:policy_ckpt=reason_r0:grasp=pads:subplan_ref=count,base:policy=vla:policy_ckpt=twin_r0,"
                                       "seal:verifier=noisy:false_positive=0.1:false_negative=0.2:grasp=pads:grip=pads:subplan_ref=count")
    assert [m.config_hash for m in (vla, twin, noisy)] == ["0c35fb9f53", "d1fec96036", "0d77a42d98"]
    (shipped,) = parse_methods("seal:policy=vla")
    (reason,) = parse_methods("seal:policy=vla:policy_ckpt=reason")  # the shipped default, named
    assert (reason.config_hash, reason.label) == (shipped.config_hash, shipped.label) != (vla.config_hash, vla.label)
    (v,) = parse_methods(f"value:value_ckpt={value}:grip=pads")
    assert v.config_hash == "34e1da3e4d"


def test_new_settings_enter_the_hash_only_when_set():
    plain = MethodSpec()
    assert MethodSpec(check_every=20, subplan_budget=200, mismatch=None).config_hash == plain.config_hash
    assert MethodSpec(mismatch=(1.3, 0.8, 1.2)).config_hash != plain.config_hash
    assert MethodSpec(subplan_budget=120).config_hash != plain.config_hash
    # where a model runs is not what it is
    assert MethodSpec(policy="remote", port=9000).config_hash == MethodSpec(policy="remote", port=8001).config_hash
    assert MethodSpec(policy="remote").config_hash != plain.config_hash
    assert MethodSpec(mismatch=(1.3, 0.8, 1.2)).label == "seal[mismatch=1.3/0.8/1.2]"
    assert MethodSpec(pick="first").config_hash == plain.config_hash
    assert MethodSpec(pick="best").label == "seal[pick=best]"
    assert MethodSpec(method="random", pick="best").config_hash == MethodSpec(method="random").config_hash
    assert MethodSpec(verify_order="slot").config_hash == plain.config_hash
    assert MethodSpec(verify_order="arrival").label == "seal[verify_order=arrival]"
    assert MethodSpec(method="base", verify_order="arrival").config_hash == MethodSpec(method="base").config_hash
    # the check changed what SEAL does by default: a new hash, and "trust" names the old behaviour
    assert MethodSpec().config_hash != MethodSpec(done_check="trust").config_hash
    assert MethodSpec(done_check="trust").label == "seal[done_check=trust]" and MethodSpec().label == "seal"
    assert MethodSpec(method="base", done_check="trust").config_hash == MethodSpec(method="base").config_hash


def test_eval_takes_verdicts_in_slot_order_and_run_as_they_arrive():
    """`seal eval`'s results must not depend on machine load; `seal run` shows the paper's overlap
    of verification and sampling unless told otherwise."""
    from seal.cli import build_parser

    parse = build_parser().parse_args
    assert parse(["eval", "--db", "r.db"]).verify_order is None  # not given: MethodSpec's default
    (m,) = parse_methods("seal")
    assert m.verify_order == "slot" and m.steer_config().verify_order == "slot"
    assert parse(["run"]).verify_order == "arrival" and parse(["run", "--verify-order", "slot"]).verify_order == "slot"
    (m,) = parse_methods("seal:verify_order=arrival")
    assert m.steer_config().verify_order == "arrival"
    with pytest.raises(InvalidInput, match="unknown verify_order 'random'; valid: slot, arrival"):
        MethodSpec(verify_order="random")


def test_parse_methods_takes_every_option():
    (m,) = parse_methods("seal:mismatch=1.3/0.8/1.2:check_every=30", policy="remote", port=9100, prompt="subplan")
    assert (m.mismatch, m.check_every, m.policy, m.port, m.prompt) == ((1.3, 0.8, 1.2), 30, "remote", 9100, "subplan")
    assert parse_mismatch("1.3,0.8,1.2") == (1.3, 0.8, 1.2) and parse_mismatch("") is None
    for bad in ("abc", "1,2", "1,2,3,4"):
        with pytest.raises(InvalidInput, match="three numbers"):
            parse_mismatch(bad)
    with pytest.raises(InvalidInput, match=r"mismatch friction=20.0 must be a factor in \[0.1, 10\]"):
        MethodSpec(mismatch=(20.0, 1.0, 1.0))


def test_registries_name_the_valid_choices():
    from seal.policies import make_policy
    from seal.steer.scoring import make_scorer
    from seal.verify import make_verifier

    with pytest.raises(InvalidInput, match="unknown policy 'octo'; valid: scripted, remote, vla"):
        make_policy("octo", MethodSpec(), None)
    with pytest.raises(InvalidInput, match="unknown verifier 'clip'; valid: oracle, openai, gemini, noisy"):
        make_verifier("clip")
    with pytest.raises(InvalidInput, match="unknown scorer 'q'; valid: value"):
        make_scorer("q", "x")
    with pytest.raises(InvalidInput, match="unknown policy 'octo'; valid: scripted, remote, vla"):
        MethodSpec(policy="octo")
    noisy = make_verifier("noisy", false_positive=0.5, seed=1)
    assert type(noisy).__name__ == "NoisyVerifier" and type(noisy.inner).__name__ == "OracleVerifier"


# ---- the CLI: bad values end in `seal: error:` and exit 2 --------------------------------------
@pytest.mark.parametrize("argv,words", [
    (["run", "--mismatch", "abc"], "--mismatch wants three numbers"),
    (["run", "--mismatch", "1.3,0.8"], "--mismatch wants three numbers"),
    (["run", "--k", "x"], "argument --k: invalid int value"),
    (["run", "--policy", "octo"], "unknown policy 'octo'"),
    (["run", "--method", "value", "--value-ckpt", "{db}"], "no V-GPS checkpoint at"),
    (["eval", "--db", "{db}", "--tasks", "0,x"], "--tasks must be comma-separated task ids"),
    (["eval", "--db", "{db}", "--tasks", "0,10"], "unknown task id 10"),
    (["eval", "--db", "{db}", "--methods", "seal:k=x"], "k='x' must be an integer (its default: k=10)"),
    (["eval", "--db", "{db}", "--methods", "seal:kk=2"], "bad method option 'kk=2'"),
    (["eval", "--db", "{db}", "--methods", "seal:mismatch=1/2"], "three numbers"),
    (["eval", "--db", "{db}", "--methods", "vgps"], "unknown method 'vgps'; valid: base, random, value, seal"),
    (["eval", "--db", "{db}", "--mismatch", "1,1,x"], "--mismatch wants three numbers"),
    (["demos", "record", "--out", "{db}", "--tasks", "a"], "--tasks must be comma-separated task ids"),
])
def test_bad_values_are_reported_not_raised(argv, words, tmp_path, capsys):
    db = tmp_path / "r.db"
    code = _exit_code(lambda: main([a.replace("{db}", str(db)) for a in argv]))
    err = capsys.readouterr().err
    assert code == 2 and "seal: error:" in err and words in err and "Traceback" not in err, err
    assert not db.exists()  # nothing was started


def _exit_code(call) -> int:
    try:
        return call()
    except SystemExit as exc:  # argparse's own errors exit from inside parse_args
        return exc.code


def test_run_and_eval_accept_the_same_method_options():
    from seal.cli import build_parser

    sub = build_parser()._subparsers._group_actions[0].choices
    flags = {name: {o for a in sub[name]._actions for o in a.option_strings} for name in ("run", "eval")}
    method_flags = {f for f in flags["run"] if f not in ("--suite", "--task", "--init", "--method", "--seed",
                                                         "--no-video", "--out", "-h", "--help")}
    assert "--policy" in method_flags and "--mismatch" in method_flags and "--planner" in method_flags
    assert method_flags <= flags["eval"], method_flags - flags["eval"]


# ---- the same method through `seal run`, `seal eval` and plug-ins ------------------------------
BOOK = ("libero_10", 5)  # two sub-plans, ~90 steps: the quickest LIBERO-10 task


def _rows(db: Path) -> list:
    from seal.eval.store import ResultStore

    with ResultStore(db, create=False) as store:
        return store.rows()


def test_run_and_eval_give_the_same_trial(tmp_path, capsys):
    """`seal run` with a trial's init state and seed == that trial's `seal eval` row and trace (in slot
    order, `seal eval`'s default, the trace is the same but for its clock readings)."""
    from seal.steer.trace import read_trace, same_episode

    suite, task = BOOK
    seed = trial_seed(suite, task, 0)
    options = ["--k", "2", "--knobs", "misaligned", "--max-steps", str(SHORT)]
    assert main(["run", "--suite", suite, "--task", str(task), "--init", "0", "--seed", str(seed), "--method", "seal",
                 "--out", str(tmp_path / "run"), "--no-video", "--no-grids", "--verify-order", "slot", *options]) == 0
    ran = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert ran["verify_order"] == "slot" and ran["method"]["method"] == "seal" and len(ran["config_hash"]) == 10
    db = tmp_path / "r.db"
    assert main(["eval", "--suite", suite, "--tasks", str(task), "--trials", "1", "--methods", "seal", "--db", str(db),
                 "--out", str(tmp_path / "eval"), "--video", "none", "--no-grids", *options]) == 0
    (row,) = _rows(db)
    assert row.status == "ok" and row.seed == seed and row.init_index == 0
    assert (row.success, row.steps, row.rounds, row.verifier_calls, row.fallbacks) == \
        (ran["success"], ran["steps"], ran["rounds"], ran["verifier_calls"], ran["fallbacks"])
    assert row.subplans == ran["subplans"] and row.goal_status == ran["goal_status"]
    assert same_episode(Path(row.trace_path), Path(ran["trace"]))
    assert ran["steps"] > 0 and any(e["event"] == "commit" for e in read_trace(Path(ran["trace"])))


def test_eval_with_a_physics_mismatch(tmp_path):
    """`seal eval --mismatch`: its own method in the store, and the pool really runs that physics."""
    from seal.eval.execute import RunOptions, TrialRunner
    from seal.eval.trials import expand

    db = tmp_path / "r.db"
    assert main(["eval", "--suite", BOOK[0], "--tasks", str(BOOK[1]), "--trials", "1", "--methods", "base,seal",
                 "--k", "2", "--mismatch", "1.3,0.8,1.2", "--max-steps", str(SHORT), "--db", str(db), "--video", "none",
                 "--out", str(tmp_path / "runs")]) == 0
    rows = _rows(db)
    assert sorted(r.method for r in rows) == ["base[mismatch=1.3/0.8/1.2]", "seal[k=2,mismatch=1.3/0.8/1.2]"]
    assert all(r.status == "ok" and r.steps > 0 for r in rows), [r.error for r in rows]
    # The worker's pool is built with the mismatch (and a plain method gets a plain pool).
    (spec,) = expand(parse_methods("base", mismatch=(1.3, 0.8, 1.2)), [BOOK[0]], [BOOK[1]], trials=1)
    runner = TrialRunner(RunOptions(out_dir=str(tmp_path / "direct"), video="none", max_steps=10))
    try:
        pool = runner._pool_for(spec, 1)
        assert pool.physics is not None and (pool.physics.friction, pool.physics.mass) == (1.3, 0.8)
        (plain,) = expand(parse_methods("base"), [BOOK[0]], [BOOK[1]], trials=1)
        assert runner._pool_for(plain, 1).physics is None
    finally:
        runner.close()


def test_eval_with_a_remote_policy(tmp_path):
    """`seal eval --methods seal --policy remote`: the trials' policy is a `seal serve` process."""
    from seal.serving.server import ServerProcess

    db = tmp_path / "r.db"
    with ServerProcess(["--knobs", "misaligned"]) as server:
        code = main(["eval", "--suite", BOOK[0], "--tasks", str(BOOK[1]), "--trials", "1", "--methods", "seal",
                     "--policy", "remote", "--port", str(server.port), "--k", "2", "--max-steps", str(SHORT),
                     "--db", str(db), "--video", "none", "--no-grids", "--out", str(tmp_path / "runs")])
    assert code == 0
    (row,) = _rows(db)
    assert row.status == "ok", row.error
    assert row.method == "seal[k=2,policy=remote]" and row.steps > 0 and row.verifier_calls > 0
