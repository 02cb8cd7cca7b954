"""`seal bench ...`: one benchmark of seal.benchmarks, printed as one JSON object."""

from __future__ import annotations

import json

from seal.cli.common import COUNT, INDEX, NONNEGATIVE, RATE


def add(sub) -> None:
    bench = sub.add_parser("bench", help="benchmarks; each prints one JSON object")
    from seal.benchmarks import BENCHMARKS

    bench.add_argument("what", choices=list(BENCHMARKS))
    bench.add_argument("--ckpt", default=None, help="vla/grasp: checkpoint (default: a random-init model of the default "
                                                     "config; 'reason'/'twin': the shipped ones); value: trained value runs "
                                                     "(comma-separated) to score on --data")
    bench.add_argument("--annotations", default=None, help="vla: annotations for the held-out figures")
    bench.add_argument("--size", default=None, help="vla without --ckpt: a size preset (S, M = default, L, M-p8, "
                                                     "M-e192x3)")
    bench.add_argument("--sizes", default=None, help="vla: also time training steps of these presets (e.g. S,M,L)")
    bench.add_argument("--dataset", default=None, help="annotate/value/vla: LeRobot dataset directory")
    bench.add_argument("--steps", type=COUNT, default=None, help="value: training updates on --dataset (default 300)")
    bench.add_argument("--backend", default="offline", choices=["offline", "gemini", "openai"],
                       help="annotate: annotation backend")
    bench.add_argument("--model", default=None, help="annotate/verifier: model name (gemini/openai)")
    bench.add_argument("--base-url", default=None, help="annotate/verifier: model server URL")
    bench.add_argument("--ks", default="", help="runtime: comma-separated K values (default 1,2,4,8,10)")
    bench.add_argument("--latency", type=NONNEGATIVE, default=2.0, help="runtime: fixed verifier latency in seconds")
    bench.add_argument("--policy", default=None,
                       help="runtime: scripted (state only), pixels (the expert reading both cameras every chunk, "
                            "a VLA's rendering without its network) or vla[:PATH]; steer/verifier-sweep: the policy "
                            "(default scripted); eval: the policy both methods run (default scripted, misaligned)")
    bench.add_argument("--budgets", default=None, metavar="F[,F]",
                       help="render: also the fast model with its mesh tolerances F times looser, timed taking "
                            "turns with the shipped one (e.g. 3,6)")
    bench.add_argument("--image-size", type=COUNT, default=None, help="runtime: camera px for pixel policies (64); render: the size measured (64)")
    bench.add_argument("--render", default=None, choices=["stock", "fast"],
                       help="runtime: render model (default: fast for pixel policies)")
    bench.add_argument("--plot", default=None, help="runtime: write the stacked breakdown against K to this PNG; "
                                                   "vla --redraw: write the round plot here (default: beside the log)")
    bench.add_argument("--dart", type=NONNEGATIVE, default=0.0,
                       help="expert: perturb every executed chunk by a Gaussian offset of this std (as `seal demos "
                            "record --dart` does): how much perturbation the expert survives")
    bench.add_argument("--record-reference", action="store_true",
                       help="vla with --ckpt: write this machine's reference rollout (an action digest) into the "
                            "checkpoint's manifest; without it the bench reports whether this machine reproduces it")
    bench.add_argument("--round-log", default=None, metavar="ROUNDS.jsonl",
                       help="vla --rollouts: append the held-out figures to this log as --round-name and redraw "
                            "ROUNDS.png (success, on-policy sub-plan accuracy, alignment per DAgger round)")
    bench.add_argument("--redraw", action="store_true",
                       help="vla --round-log: redraw ROUNDS.png from the log and stop (nothing is measured)")
    bench.add_argument("--round-name", default=None, help="vla --round-log: the round's label (default: the checkpoint)")
    bench.add_argument("--round", action="append", default=None, metavar="NAME",
                       help="vla --redraw: plot only this logged round (repeat; the plot keeps this order)")
    bench.add_argument("--noise-scale", type=NONNEGATIVE, default=1.0,
                       help="vla --rollouts: scale of the flow's starting noise (1: as trained; 0: the chunk from zero "
                            "noise), the policy option noise_scale")
    bench.add_argument("--rollouts", type=INDEX, default=0,
                       help="vla with --ckpt: closed-loop episodes per task on fresh sampled starts (default 0: none); "
                            "grasp: episodes on --task (default 4)")
    bench.add_argument("--tasks", default="", help="comma-separated task ids (expert: all; steer: 0,1,7; runtime: 5; render: 0,3,9; "
                                                  "labels: 0,2,5)")
    bench.add_argument("--trials", type=COUNT, default=None,
                       help="expert/steer/runtime: trials (init states) per task (default 50); eval: trials per "
                            "task (default 3); serve: round trips (default 50); labels: expert episodes per task "
                            "(default 1)")
    bench.add_argument("--max-steps", type=COUNT, default=None,
                       help="steer/runtime/eval: control steps per episode (default: the suite's limit)")
    bench.add_argument("--no-misaligned", action="store_true", help="expert: skip the misaligned setting")
    bench.add_argument("--grip", default=None,
                       help="expert: how it tells an object is in its hand, one or both of fingers (Held, the default) "
                            "and pads (robosuite's Grasped, the expert before 2026-12-05), e.g. fingers,pads; "
                            "each runs on the same inits")
    bench.add_argument("--stock-step", action="store_true",
                       help="eval: run the SEAL trials again on robosuite's own control step and report the fast "
                            "step's trials/hour ratio (same episodes, one run)")
    bench.add_argument("--no-ray", action="store_true", help="eval: skip the Ray-versus-local comparison")
    bench.add_argument("--first-init", type=INDEX, default=0,
                       help="expert: first official init state (trials run first-init .. first-init+trials-1)")
    bench.add_argument("--log", default=None,
                       help="expert: JSONL file, one row per finished episode; re-running resumes from it")
    bench.add_argument("--suite", default="libero_10")
    bench.add_argument("--task", type=INDEX, default=0)
    bench.add_argument("--k", type=COUNT, default=10)
    bench.add_argument("--workers", type=COUNT, default=None)
    vb = bench.add_argument_group("verifier / verifier-sweep (docs/verifier.md)")
    vb.add_argument("--verifier", default="oracle",
                    help="verifier: oracle | openai | gemini | noisy | learned[:RUN_DIR]; steer: the verifier SEAL uses")
    vb.add_argument("--data", default=None, help="verifier: `seal verify collect` directory (default: a small "
                    "fresh held-out set, collected once into runs/verifier/heldout/); value: a `seal demos dagger` "
                    "collection whose rollouts --ckpt is scored on")
    vb.add_argument("--out", default=None, help="verifier: Markdown file; verifier-sweep: results directory "
                    "(default runs/verifier/sweep)")
    vb.add_argument("--limit", type=COUNT, default=None, help="verifier: score at most N cases (a fixed shuffle)")
    vb.add_argument("--false-positive", type=RATE, default=None, help="verifier noisy: false-positive rate")
    vb.add_argument("--false-negative", type=RATE, default=None, help="verifier noisy: false-negative rate")
    vb.add_argument("--threshold", type=RATE, default=None,
                    help="verifier learned: success when P(success) >= this (default: the checkpoint's)")
    vb.add_argument("--min-precision", type=RATE, default=None,
                    help="verifier learned: also report the lowest threshold reaching this precision on --data "
                         "(pick it on a calibration set, report with --threshold on another)")
    vb.add_argument("--cache-dir", default=None,
                    help="verifier openai/gemini: answer cache (default ~/.cache/seal/verifier-answers)")
    vb.add_argument("--fp", default=None, help="verifier-sweep: false-positive rates (default 0,0.1,0.2,0.4)")
    vb.add_argument("--fn", default=None, help="verifier-sweep: false-negative rates (default 0,0.2,0.4)")
    vb.add_argument("--points", default=None,
                    help="verifier-sweep: comma-separated `seal bench verifier` JSON files to draw as measured points")
    bench.set_defaults(func=_cmd_bench)


def _cmd_bench(args) -> int:
    from seal.benchmarks import run_benchmark

    print(json.dumps(run_benchmark(args.what, args)))
    return 0
