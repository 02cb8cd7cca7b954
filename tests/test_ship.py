"""Shipping a retrained VLA: the copy is checked, the replaced checkpoint stays loadable under a
name, and the manifest records the chain of fine-tunes the weights came from."""

import json
import shutil

import pytest

from seal.checkpoint import MANIFEST
from seal.errors import InvalidInput
from seal.policies.vla.locate import CHECKPOINT, SHIPPED
from seal.policies.vla.ship import lineage, ship


def _run(tmp_path, name, source, **fields):
    """A `seal train vla` run directory holding a copy of ``source`` with ``fields`` in its manifest."""
    ckpt = tmp_path / name / "checkpoint"
    shutil.copytree(source, ckpt)
    manifest = json.loads((ckpt / MANIFEST).read_text())
    manifest = {k: v for k, v in manifest.items() if k not in ("lineage", "shipped")} | fields  # a plain run
    (ckpt / MANIFEST).write_text(json.dumps(manifest))
    return tmp_path / name


def test_a_run_ships_with_its_lineage_and_the_old_checkpoint_stays_loadable(tmp_path):
    root = tmp_path / "checkpoints"
    shutil.copytree(SHIPPED["twin"], root / "reason")  # stands for the checkpoint being replaced
    old = CHECKPOINT.digest(root / "reason")
    first = _run(tmp_path, "r1", SHIPPED["reason"], command="seal train vla --steps 10", init_from=None)
    second = _run(tmp_path, "r2", SHIPPED["reason"], command="seal train vla --init-from r1",
                  init_from=str(first), sources=[{"annotations": "dagger_r1", "share": 0.5}])
    assert [link["command"] for link in lineage(str(second))] == ["seal train vla --init-from r1",
                                                                   "seal train vla --steps 10"]

    # a damaged run is refused before anything moves
    bad = _run(tmp_path, "bad", SHIPPED["reason"], init_from=None)
    with (bad / "checkpoint" / "model.safetensors").open("r+b") as f:
        f.seek(100)
        f.write(b"\x00\x01")
    with pytest.raises(InvalidInput, match="sha256"):
        ship(bad, "reason", keep_as="reason_r0", root=root)
    assert CHECKPOINT.digest(root / "reason") == old and not (root / "reason_r0").exists()
    # the checkpoint in the way needs a name to be kept under
    with pytest.raises(InvalidInput, match="keep_as"):
        ship(second, "reason", root=root)

    new = ship(second, "reason", keep_as="reason_r0", keep_label="reasoning VLA (round 0)", root=root)
    assert CHECKPOINT.digest(new) == CHECKPOINT.digest(second / "checkpoint")
    assert CHECKPOINT.digest(root / "reason_r0") == old  # kept, whole, under its new name
    manifest = json.loads((new / MANIFEST).read_text())
    assert manifest["shipped"]["name"] == "reason"
    assert [link["command"] for link in manifest["lineage"]] == ["seal train vla --init-from r1",
                                                                "seal train vla --steps 10"]
    assert manifest["lineage"][0]["sources"] == [{"annotations": "dagger_r1", "share": 0.5}]
    kept = json.loads((root / "reason_r0" / MANIFEST).read_text())["shipped"]
    assert kept["label"] == "reasoning VLA (round 0)" and kept["replaced_by"] == manifest["lineage"][0]["digest"]
    assert not list(root.glob(".*"))  # no staging left behind

    # a later fine-tune of the shipped checkpoint inherits the chain recorded when it shipped
    third = _run(tmp_path, "r3", SHIPPED["reason"], command="seal train vla --init-from reason",
                 init_from=str(new))
    assert [link.get("command") for link in lineage(str(third))] == [
        "seal train vla --init-from reason", "seal train vla --init-from r1", "seal train vla --steps 10"]
    with pytest.raises(InvalidInput, match="exists already"):
        ship(third, "reason", keep_as="reason_r0", root=root)
    with pytest.raises(InvalidInput, match="plain directory name"):
        ship(third, "../elsewhere", root=root)


def test_a_verifier_ships_with_the_benches_that_justify_it_and_the_old_one_keeps_a_name(tmp_path, capsys,
                                                                                        monkeypatch):
    from _verifier_cases import write_cases

    from seal.cli import main
    from seal.report.labels import earlier_verifiers
    from seal.verify import learned
    from seal.verify.ship import ship as ship_verifier

    root = tmp_path / "checkpoints"
    shutil.copytree(learned.DEFAULT_CHECKPOINT, root / "learned")  # the checkpoint being replaced
    old = learned.CHECKPOINT.digest(root / "learned")
    run = tmp_path / "run"  # stands for a `seal train verifier` run: another real checkpoint
    shutil.copytree(learned.SHIPPED["pad_labels"], run)
    data = write_cases(tmp_path / "cases", 12, tasks=("libero_10/0",), inits=2)

    def bench(verifier, threshold, name):
        assert main(["bench", "verifier", "--verifier", verifier, "--data", str(data), "--threshold",
                     str(threshold)]) == 0
        path = tmp_path / name
        path.write_text(capsys.readouterr().out)
        return path

    at_08, at_09 = bench(f"learned:{run}", 0.8, "run_t0.8.json"), bench(f"learned:{run}", 0.9, "run_t0.9.json")
    other = bench("learned", 0.8, "shipped_t0.8.json")
    kw = dict(keep_as="held_labels", keep_label="the round-2 VLA's rounds", why="test", root=root)

    # refused, with nothing moved: a bench of another checkpoint, no bench at the operating point, a damaged run
    with pytest.raises(InvalidInput, match="not learned:"):
        ship_verifier(run, operating_point=0.8, held_out={"subplan_protocol": other}, **kw)
    with pytest.raises(InvalidInput, match="operating point 0.8"):
        ship_verifier(run, operating_point=0.8, held_out={"subplan_protocol": at_09}, **kw)
    bad = tmp_path / "bad"
    shutil.copytree(run, bad)
    with (bad / "model.safetensors").open("r+b") as f:
        f.seek(200)
        f.write(b"\x00\x01")
    with pytest.raises(InvalidInput, match="sha256"):
        ship_verifier(bad, operating_point=0.8, held_out={"subplan_protocol": at_08}, **kw)
    assert learned.CHECKPOINT.digest(root / "learned") == old and not (root / "held_labels").exists()

    new = ship_verifier(run, operating_point=0.8, held_out={"subplan_protocol": at_08, "t0.9": at_09}, **kw)
    assert learned.CHECKPOINT.digest(new) == learned.CHECKPOINT.digest(run)
    assert learned.CHECKPOINT.digest(root / "held_labels") == old  # kept, whole, under its new name
    shipped = json.loads((new / MANIFEST).read_text())["shipped"]
    assert shipped["operating_point"] == 0.8 and shipped["replaces"] == f"{old} (now learned:held_labels)"
    figures = json.loads(at_08.read_text())
    assert shipped["held_out"]["subplan_protocol"]["n"] == 12 == figures["n"]
    assert shipped["held_out"]["subplan_protocol"]["accuracy"] == figures["accuracy"]
    assert shipped["held_out"]["t0.9"]["threshold"] == 0.9
    assert not list(root.glob(".*"))  # no staging left behind
    # reports name rows of the kept checkpoint by the label it was given
    monkeypatch.setattr(learned, "SHIPPED", {"held_labels": root / "held_labels"})
    assert earlier_verifiers() == {old: "learned verifier from the round-2 VLA's rounds"}
    with pytest.raises(InvalidInput, match="exists already"):
        ship_verifier(run, operating_point=0.8, held_out={"subplan_protocol": at_08}, **kw)
