"""`seal ground`: the goal atoms the oracle verifier checks for a sub-plan text."""

from __future__ import annotations

import json


def add(sub) -> None:
    gr = sub.add_parser("ground", help="the goal atoms the oracle verifier checks for a sub-plan text")
    gr.add_argument("text", help='e.g. "place it in the basket"')
    gr.add_argument("--suite", default="libero_10")
    gr.add_argument("--task", type=int, default=0)
    gr.add_argument("--plan", nargs="*", default=None,
                    help="earlier sub-plans, so 'it' can be resolved (default: the expert's plan)")
    gr.set_defaults(func=_cmd_ground)


def _cmd_ground(args) -> int:
    from seal.policies.expert.plan import plan_task
    from seal.sim.suites import get_task
    from seal.sim.world import LiberoWorld
    from seal.verify.oracle import ground

    spec = get_task(args.suite, args.task)
    world = LiberoWorld(spec)  # the scene's exact object and region names
    names = world.objects
    world.close()
    plans = tuple(args.plan) if args.plan else tuple(p.text for p in plan_task(spec))
    index = len(args.plan) if args.plan else (plans.index(args.text) if args.text in plans else None)
    g = ground(args.text, plans, names, index)
    print(json.dumps({"task": spec.key, "text": args.text,
                      "atoms": [str(a) for a in g.atoms] if g.atoms else "unknown",
                      **({"reason": g.reason} if not g.atoms else {})}))
    return 0
