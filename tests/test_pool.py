import os
import signal
import threading

import numpy as np
import pytest

from seal.errors import InvalidInput
from seal.sim.pool import EnvPool, wait_awake

CHUNKS = [np.random.default_rng(s).uniform(-1, 1, (5, 7)) for s in range(4)]


@pytest.fixture(scope="module")
def pool():
    with EnvPool(("libero_10", 0), k=4, workers=2) as p:
        yield p


def test_pool_matches_single_process_world(pool, world):
    start = pool.reset(0)
    world.reset(0)
    assert world.snapshot() == start
    results = pool.step(CHUNKS)
    assert [r.slot for r in results] == [0, 1, 2, 3] and all(r.ok and r.steps == 5 for r in results)
    for r, chunk in zip(results, CHUNKS):
        world.restore(start)
        world.step_chunk(chunk)
        assert world.snapshot() == r.snapshot  # same bits as stepping in this process
    assert len({r.snapshot.id for r in results}) == 4  # different chunks, different outcomes


def test_sync_moves_every_slot_to_the_winner(pool):
    pool.reset(0)
    winner = pool.step({2: CHUNKS[2]})[0].snapshot
    pool.sync(winner)
    assert all(pool.snapshot(s) == winner for s in range(4))
    obs = pool.observe()
    assert all(np.array_equal(o.agent, obs[0].agent) for o in obs)  # renders agree across workers
    assert pool.check(["In(alphabet_soup_1, basket_1_contain_region)"]) == [
        {"In(alphabet_soup_1, basket_1_contain_region)": False}] * 4


def test_killed_worker_is_respawned_and_only_its_slots_fail(pool):
    start = pool.reset(0)
    victim = 1  # owns slots 1 and 3
    pid = pool.worker_pids()[victim]
    # ~300 steps per worker (several seconds): the kill lands mid-command on any machine
    long_chunks = [np.zeros((150, 7))] * 4
    threading.Timer(0.5, os.kill, (pid, signal.SIGKILL)).start()
    results = pool.step(long_chunks)
    failed = {r.slot for r in results if not r.ok}
    assert failed == set(pool.slots_of(victim)) == {1, 3}
    assert all("died" in r.error for r in results if r.slot in failed)
    assert pool.worker_pids()[victim] != pid and pool.crashes >= 1
    # the survivors moved on; the victim's slots are back at their last snapshot and usable
    assert pool.snapshot(0).steps == 150 and pool.snapshot(1) == pool.snapshot(3) == start
    again = pool.step({1: CHUNKS[1], 3: CHUNKS[1]})
    assert all(r.ok and r.snapshot.steps == 5 for r in again) and again[0].snapshot == again[1].snapshot


def test_pool_bad_input(pool):
    with pytest.raises(InvalidInput, match="valid: 0..3"):
        pool.step({7: CHUNKS[0]})
    with pytest.raises(InvalidInput, match=r"shape \(n, 7\)"):
        pool.step({0: np.zeros((5, 6))})
    with pytest.raises(InvalidInput, match="valid: 0..49"):
        pool.reset(99)
    with pytest.raises(InvalidInput, match="workers must be in 1..2"):
        EnvPool(("libero_10", 0), k=2, workers=3)


def test_worker_killed_between_commands_is_noticed_on_the_next_one(pool):
    start = pool.reset(0)
    pid = pool.worker_pids()[0]  # owns slots 0 and 2
    os.kill(pid, signal.SIGKILL)
    results = pool.step(CHUNKS)
    assert {r.slot for r in results if not r.ok} == {0, 2}
    assert pool.worker_pids()[0] != pid
    assert pool.snapshot(0) == start and all(r.ok for r in pool.step(CHUNKS))


def test_a_pause_of_the_whole_run_does_not_spend_a_workers_timeout():
    """Ctrl-Z or SIGSTOP pauses the workers too: the pause is not time they failed to answer in."""
    now, calls = [0.0], []

    def clock():
        return now[0]

    def paused_once(objects, t):  # the second slice spans a 1000 s pause; the answer comes in the fourth
        calls.append(t)
        now[0] += 1000.0 if len(calls) == 2 else t
        return ["answer"] if len(calls) == 4 else []

    assert wait_awake(["conn"], 20.0, waiter=paused_once, clock=clock) == ["answer"]

    def silent(objects, t):
        calls.append(t)
        now[0] += t
        return []

    calls.clear()
    assert wait_awake(["conn"], 12.0, waiter=silent, clock=clock) == [] and calls == [5.0, 5.0, 2.0]
