"""The oracle's pick check: ``Held`` (each finger on the object, pad or body) against robosuite's
``Grasped`` (both pads), in a real LIBERO world, and which one the oracle asks for."""

import pytest
from _worlds import world_at

from seal.episode import run_policy_episode
from seal.errors import InvalidInput
from seal.policies.expert.policy import ScriptedExpert
from seal.sim.scene import SceneReader
from seal.steer.method import parse_methods
from seal.verify import verifier_for
from seal.verify.base import VerifyRequest
from seal.verify.oracle import OracleVerifier

POT = "moka_pot_1"
PLANS = ("pick up the first moka pot", "place it on the stove")


@pytest.fixture(scope="module")
def stove_world():
    with world_at("libero_10", 8) as w:
        yield w


def test_held_counts_every_pad_grasp_and_the_expert_picks_the_pot(stove_world):
    world = stove_world
    seen = {"grasped": 0, "held": 0, "grasped_not_held": 0}

    def probe(_step, _max):
        grasped, held = world.check(f"Grasped({POT})"), world.check(f"Held({POT})")
        seen["grasped"] += grasped
        seen["held"] += held
        seen["grasped_not_held"] += grasped and not held

    assert not world.check(f"Held({POT})") and not world.check(f"Grasped({POT})")  # the pot stands on the table
    run_policy_episode(world, ScriptedExpert.for_world(world), init_index=0, max_steps=160, progress=probe)
    # the pads are part of the fingers: a pad grasp is always a hold, and the expert's pick is both
    assert seen["grasped_not_held"] == 0
    assert seen["grasped"] > 10 and seen["held"] >= seen["grasped"], seen
    with pytest.raises(InvalidInput, match="unknown object"):
        world.check("Held(no_such_pot_1)")


def test_what_the_grasp_bench_reads_from_a_scene(stove_world):
    from seal.benchmarks.grasp import moved_objects, touches

    stove_world.reset(0)
    assert moved_objects(stove_world) == ["moka_pot_1", "moka_pot_2"]  # the goal's two In/On subjects
    assert touches(stove_world._env, POT) == (False, True)  # standing on the stove's table, the gripper away


def test_the_oracle_asks_for_held_unless_told_pads(stove_world):
    names = stove_world.objects
    request = VerifyRequest(subplan=PLANS[0], instruction="put both moka pots on the stove", plans=PLANS, index=0)
    assert OracleVerifier().atoms_needed(request, names) == [f"Held({POT})"]
    assert OracleVerifier(grasp="pads").atoms_needed(request, names) == [f"Grasped({POT})"]
    place = VerifyRequest(subplan=PLANS[1], instruction="", plans=PLANS, index=1)
    assert OracleVerifier().atoms_needed(place, names) == OracleVerifier(grasp="pads").atoms_needed(place, names)
    # a verdict reads the fact it asked for (a scene that held the pot by a finger's body, not its pad)
    request.scene = SceneReader(stove_world._env).read({f"Held({POT})": True, f"Grasped({POT})": False})
    assert OracleVerifier().judge(request).success is True
    assert OracleVerifier(grasp="pads").judge(request).success is False
    # a case recorded before the Held check carries only the pad fact: it is judged by what was recorded
    request.scene = SceneReader(stove_world._env).read({f"Grasped({POT})": True})
    verdict = OracleVerifier().judge(request)
    assert verdict.success is True and verdict.rationale == f"Grasped({POT}) is true"
    with pytest.raises(InvalidInput, match="valid: fingers, pads"):
        OracleVerifier(grasp="palm")


def test_the_grasp_check_is_a_method_setting_that_keeps_earlier_hashes():
    new, old = parse_methods("seal:policy=vla,seal:policy=vla:grasp=pads")
    assert new.canonical()["grasp"] == "fingers" and "grasp" not in old.canonical()  # the stored rows' config
    assert new.config_hash != old.config_hash
    assert verifier_for(new).grasp == "fingers" and verifier_for(old).grasp == "pads"
    noisy, = parse_methods("seal:policy=vla:verifier=noisy:false_positive=0.1:grasp=pads")
    assert verifier_for(noisy).inner.grasp == "pads"
    with pytest.raises(InvalidInput, match="grasp"):
        parse_methods("seal:policy=vla:verifier=learned:grasp=pads")  # the learned verifier has no such check


def test_the_expert_keeps_carrying_what_the_pads_miss(stove_world):
    """A pot on a finger's body and not on the pads (how the VLA often carries one, `seal bench grasp`): the
    default expert reads it as in hand and goes on to place it; the pad-check expert (every recording before
    2026-12-05) took it for not picked, and its DAgger labels said "pick up" while the pot was in the air."""
    import numpy as np

    from seal.sim.observation import Observation

    stove_world.reset(0)
    fingers, pads = ScriptedExpert.for_world(stove_world), ScriptedExpert.for_world(stove_world, grip="pads")
    assert f"Held({POT})" in fingers.privileged_atoms() and f"Grasped({POT})" not in fingers.privileged_atoms()
    assert f"Grasped({POT})" in pads.privileged_atoms() and f"Held({POT})" not in pads.privileged_atoms()
    facts = {a: stove_world.check(a) for a in fingers.privileged_atoms() + pads.privileged_atoms()}
    facts |= {f"Held({POT})": True, f"Grasped({POT})": False}
    obs = Observation(state=np.zeros(8), prompt=stove_world.instruction, scene=SceneReader(stove_world._env).read(facts))
    now_fingers, now_pads = fingers.reason(obs).now, pads.reason(obs).now
    assert now_pads.startswith("pick up") and "moka pot" in now_pads
    assert not now_fingers.startswith("pick up") and "stove" in now_fingers, now_fingers
    with pytest.raises(InvalidInput, match="valid: fingers, pads"):
        ScriptedExpert.for_world(stove_world, grip="palm")
