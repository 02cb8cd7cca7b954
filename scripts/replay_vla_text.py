#!/usr/bin/env python
"""Replay one of `seal bench vla --rollouts`'s held-out episodes and print where the VLA's sub-plan and the
scripted expert's part (maintainers' tool): the reasoning the VLA acts on against the teacher's, at each chunk
boundary where either changes, and optionally a strip of frames (agent view over wrist view) to look at.

    python scripts/replay_vla_text.py --ckpt reason --task 9 --episode 0 [--frames 15,18,30 --png strip.png]

Same start, same seed and the same labelled rollout as the bench (`seal.benchmarks.vla._labelled_rollouts`).
"""

import argparse
import sys

import numpy as np

from seal.errors import InvalidInput


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--ckpt", default="reason", help="a reasoning VLA checkpoint (default: the shipped one)")
    p.add_argument("--suite", default="libero_10")
    p.add_argument("--task", type=int, required=True)
    p.add_argument("--episode", type=int, default=0, help="the bench's episode number on that task (0, 1, ...)")
    p.add_argument("--render", default="fast")
    p.add_argument("--frames", default="", help="comma-separated chunk boundaries to draw (with --png)")
    p.add_argument("--png", default=None, help="write the frames as one strip here")
    args = p.parse_args()

    from seal.benchmarks.vla import ROLLOUT_EPISODE0, rollout_start_seed
    from seal.dagger import DaggerJob, release_cached, run_dagger_episode
    from seal.policies.vla.checkpoint import read_config
    from seal.policies.vla.locate import resolve_checkpoint
    from seal.sim.suites import get_task

    try:
        where = resolve_checkpoint(args.ckpt)
        cfg = read_config(where)
        if not cfg.reasoning:
            raise InvalidInput(f"{args.ckpt} writes no sub-plans (a twin): nothing to compare")
        task = get_task(args.suite, args.task)
        frames = [int(f) for f in args.frames.split(",") if f.strip()]
    except (InvalidInput, ValueError) as exc:
        print(f"replay_vla_text: error: {exc}", file=sys.stderr)
        return 2
    job = DaggerJob(args.suite, args.task, ROLLOUT_EPISODE0 + args.episode, 0, str(where), 0.0, args.render,
                    cfg.image_size, None, start_seed=rollout_start_seed(task, args.episode), closed_loop=False)
    try:
        _, attempt, episode, rows = run_dagger_episode(job)
    finally:
        release_cached()
    print(f"{task.key} episode {args.episode}: success={attempt['success']} steps={attempt['steps']} "
          f"sub-plan accuracy={attempt['subplan_accuracy']}")
    last = None
    for i, r in enumerate(rows):
        if (r["vla_now"], r["now"]) != last:
            print(f"boundary {i:3d} (step {r['step']:3d})  VLA: {r['vla_now']!r:40}  teacher: {r['now']!r}")
            last = (r["vla_now"], r["now"])
    if args.png and frames and episode is not None:
        import imageio.v3 as iio

        bad = [f for f in frames if not 0 <= f < len(episode.agent_images)]
        if bad:
            print(f"replay_vla_text: error: --frames {bad} outside 0..{len(episode.agent_images) - 1}", file=sys.stderr)
            return 2
        strip = np.concatenate([np.concatenate([episode.agent_images[f], episode.wrist_images[f]]) for f in frames], 1)
        iio.imwrite(args.png, strip)
        print(f"frames {frames} -> {args.png} (agent view over wrist view); gripper qpos "
              f"{[np.round(episode.states[f][6:], 3).tolist() for f in frames]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
