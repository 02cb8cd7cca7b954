"""The oracle's graded miss score: what SEAL's fallback ranks when no candidate of a sub-plan passes.

With ``miss_score=zero`` every miss scores 0 and the fallback commits the first candidate; with
``graded`` a miss scores how close its end state came, so the fallback commits the one that got
furthest (LIBERO-10 task 9: the VLA's "close the microwave" segments end before the door shuts).
"""

from __future__ import annotations

import numpy as np
import pytest

from _worlds import world_at
from seal.errors import InvalidInput
from seal.report.labels import display_name
from seal.steer.method import parse_methods
from seal.steer.result import SteerResult
from seal.steer.selection import Candidate, SealSelection
from seal.verify import make_verifier
from seal.verify.base import Verdict, VerifyRequest
from seal.verify.oracle import OracleVerifier

PLANS = ("pick up the yellow and white mug", "place it in the microwave", "close the microwave")


@pytest.fixture(scope="module")
def microwave():
    with world_at("libero_10", 9) as w:
        yield w


def _judge(world, oracle: OracleVerifier, index: int):
    request = VerifyRequest(subplan=PLANS[index], instruction=world.instruction, plans=PLANS, index=index)
    scene = world.scene_state()
    objects = sorted(set(scene.bodies) | set(scene.sites))
    request.scene = world.scene_state(oracle.atoms_needed(request, objects))
    return oracle.judge(request)


def _set_joint(world, joint: str, value) -> None:
    sim = world._env.sim
    sim.data.set_joint_qpos(joint, value)
    sim.forward()


def test_a_door_scores_by_how_far_it_shut_and_a_shut_door_passes(microwave):
    graded, zero = OracleVerifier(miss_score="graded"), OracleVerifier()
    start = microwave.scene_state().articulations["microwave_1_microjoint"].qpos
    scores = []
    for q in (start, -1.0, -0.4, -0.1):
        _set_joint(microwave, "microwave_1_microjoint", q)
        v = _judge(microwave, graded, 2)
        assert v.success is False and _judge(microwave, zero, 2).score == 0.0
        scores.append(v.score)
    assert all(b > a for a, b in zip(scores, scores[1:])), scores
    assert 0.0 < scores[0] < 0.3 and 0.9 < scores[-1] < 0.99
    _set_joint(microwave, "microwave_1_microjoint", 0.0)
    shut = _judge(microwave, graded, 2)
    assert shut.success is True and shut.score == 1.0
    _set_joint(microwave, "microwave_1_microjoint", start)


def test_a_place_scores_by_how_near_the_object_came_to_its_region(microwave):
    graded = OracleVerifier(miss_score="graded")
    state = microwave._env.sim.data.get_joint_qpos("white_yellow_mug_1_joint0").copy()
    region = microwave.scene_state().sites["microwave_1_heating_region"].pos
    scores = []
    for t in (0.0, 0.5):  # the mug moved part of the way, in the air (a miss at every point)
        q = state.copy()
        q[:3] = (1 - t) * state[:3] + t * (region + np.array([0, 0, 0.25]))
        _set_joint(microwave, "white_yellow_mug_1_joint0", q)
        v = _judge(microwave, graded, 1)
        assert v.success is False
        scores.append(v.score)
    _set_joint(microwave, "white_yellow_mug_1_joint0", state)
    assert 0.0 < scores[0] < scores[1] < 0.99


def test_the_fallback_commits_the_candidate_that_came_closest():
    def cand(slot: int, score: float) -> Candidate:
        return Candidate(round=0, slot=slot, ended_by="think", verdict=Verdict(False, "", score=score))

    result = SteerResult(task="libero_10/9", instruction="", init_index=0, method="seal")
    picked = SealSelection().fallback([cand(0, 0.1), cand(1, 0.7), cand(2, 0.4)], np.random.default_rng(0), result)
    assert picked.slot == 1 and result.fallbacks == 1
    zeros = [cand(0, 0.0), cand(1, 0.0)]
    assert SealSelection().fallback(zeros, np.random.default_rng(0), result).slot == 0


def test_the_option_keeps_every_stored_hash_and_reads_in_reports():
    plain, zero, graded = (parse_methods(f"seal:policy=vla:k=10{extra}")[0]
                           for extra in ("", ":miss_score=zero", ":miss_score=graded"))
    assert plain.config_hash == zero.config_hash != graded.config_hash
    assert display_name(graded.canonical()) == "reasoning VLA + SEAL (oracle, graded fallback)"
    assert make_verifier("oracle", miss_score="graded").miss_score == "graded"
    with pytest.raises(InvalidInput, match="valid: zero, graded"):
        OracleVerifier(miss_score="partial")
    with pytest.raises(InvalidInput, match="miss_score is for the oracle"):
        parse_methods("seal:policy=vla:k=10:verifier=learned:miss_score=graded")
