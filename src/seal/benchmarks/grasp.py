"""`seal bench grasp`: does the oracle's pick check agree with the object being in the hand?

A pick sub-plan is verified by a contact check. robosuite's (``Grasped``) wants both finger *pads*
on the object; ``Held`` (the oracle's default since 2026-12-05) takes either surface of each finger.
This bench rolls a policy out (default: the shipped reasoning VLA, the policy SEAL steers) on
``--rollouts`` held-out fresh starts of ``--task`` (the starts `seal bench vla` uses, never an
official init state) and, at every control step, for every object the task's goal moves, reads:

- ``up``: the object has risen more than 3 cm above where it started and touches nothing but the
  gripper: in the hand by any reading of the scene;
- ``grasped`` / ``held``: the two contact checks.

It prints, per object, the steps it was up and the share of them each check passes
(``grasped_when_up``, ``held_when_up``), and the steps each check passes while the object is not up
(``grasped_not_up``, ``held_not_up``: closing on an object still on the table, or a check passing
on a touch). A check that misses steps where the object is up turns a real pick into a refusal
in SEAL's oracle rounds and a wrong label in the verifier's training cases.
"""

from __future__ import annotations

import time

from seal.errors import InvalidInput

RISE_M = 0.03  # how far above its start an object must be to count as lifted


def touches(env, obj: str) -> tuple[bool, bool]:
    """(touches the gripper, touches anything else) for ``obj``'s collision geoms, now."""
    contacts = env.get_contacts(env.get_object(obj))  # robosuite: geoms touching the object's own
    gripper = set(env.robots[0].gripper.contact_geoms)
    return bool(contacts & gripper), bool(contacts - gripper)


def moved_objects(world) -> list[str]:
    """The objects the task's goal places somewhere (the first argument of each In/On atom)."""
    return sorted({a.args[0] for a in world.goal_atoms if a.predicate in ("in", "on")})


def run(args) -> dict:
    from seal.benchmarks.vla import rollout_start_seed
    from seal.episode import run_policy_episode
    from seal.policies.vla.policy import VLAPolicy
    from seal.sim.suites import get_task
    from seal.sim.world import LiberoWorld

    episodes = args.rollouts or 4
    ckpt = args.ckpt or "reason"
    world = LiberoWorld(get_task(args.suite, args.task), render_mode=args.render or "fast")
    try:
        objects = moved_objects(world)
        if not objects:
            raise InvalidInput(f"{world.task.key}: its goal moves no object (no In/On atom); pick another --task")
        policy = VLAPolicy.load(ckpt)
        env = world._env
        counts = {o: dict(steps=0, up=0, grasped_when_up=0, held_when_up=0, grasped_not_up=0, held_not_up=0)
                  for o in objects}
        rows, start = [], time.perf_counter()
        for e in range(episodes):
            seed = rollout_start_seed(world.task, e)
            z0: dict[str, float] = {}

            def probe(_step, _max):
                for o in objects:
                    z = float(world.object_position(o)[2])
                    z0.setdefault(o, z)
                    grip, other = touches(env, o)
                    up = z - z0[o] > RISE_M and grip and not other
                    grasped, held = world.check(f"Grasped({o})"), world.check(f"Held({o})")
                    c = counts[o]
                    c["steps"] += 1
                    c["up"] += up
                    c["grasped_when_up" if up else "grasped_not_up"] += grasped
                    c["held_when_up" if up else "held_not_up"] += held

            r = run_policy_episode(world, policy, init_index=0, start_seed=seed, progress=probe)
            rows.append(dict(start_seed=seed, success=r.success, steps=r.steps))
    finally:
        world.close()
    for c in counts.values():
        for check in ("grasped", "held"):
            c[f"{check}_share_when_up"] = round(c[f"{check}_when_up"] / c["up"], 3) if c["up"] else None
    return dict(task=world.task.key, ckpt=ckpt, episodes=rows, rise_m=RISE_M, objects=counts,
                wall_s=round(time.perf_counter() - start, 1))
