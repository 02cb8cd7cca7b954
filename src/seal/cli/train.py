"""`seal train value|vla|verifier`: datasets to checkpoints."""

from __future__ import annotations

import argparse
import contextlib
import json
from pathlib import Path

from seal.cli.common import COUNT, FRACTION, POSITIVE, RATE
from seal.errors import InvalidInput
from seal.options import real_in


def add(sub) -> None:
    train = sub.add_parser("train", help="learned models: `value` (the V-GPS baseline's IQL Q-function), `vla` "
                                         "(the reasoning VLA or, with --no-reasoning, its pi0 twin), `verifier` "
                                         "(the learned verifier, docs/verifier.md)")
    train.add_argument("what", choices=["value", "vla", "verifier"])
    train.add_argument("--dataset", default=None,
                       help="LeRobot dataset (value: required; vla: default the one the annotations name)")
    train.add_argument("--out", required=True, help="run directory (re-running continues from its checkpoint)")
    train.add_argument("--steps", type=COUNT, default=None, help="gradient updates (value 3000, vla 9000, verifier 2000)")
    train.add_argument("--batch-size", "--batch", dest="batch_size", type=COUNT, default=None,
                       help="value 128, vla 32, verifier 64")
    train.add_argument("--lr", type=POSITIVE, default=None, help="value 3e-4, vla 3e-4 (cosine decay), verifier 1e-3")
    train.add_argument("--holdout", type=FRACTION, default=None,
                       help="fraction of episodes held out for the check (value 0.2, vla 0.1)")
    train.add_argument("--seed", type=int, default=None)
    train.add_argument("--threads", type=COUNT, default=None, help="vla/verifier: torch threads (default 1)")
    train.add_argument("--init-from", default=None, metavar="CKPT",
                       help="vla/verifier: fine-tune this checkpoint instead of training from scratch. vla: reason, "
                            "twin or a directory (its shape, tokenizer and normalization; --model-config is ignored); "
                            "verifier: learned (the shipped one) or a run directory (its vocabulary and input size)")
    value = train.add_argument_group("value")
    value.add_argument("--goals", default="both", choices=["task", "subplan", "both"],
                       help="goal texts to condition on: the task instruction, each sub-plan, or both")
    value.add_argument("--rollouts", default=None, metavar="DIR[,DIR]",
                       help="`seal demos dagger` collections (their OUT directories) whose executed chunks add a "
                            "policy's own transitions, failures included, to the demonstrations")
    value.add_argument("--gamma", type=RATE, default=0.9, help="discount per 5-step chunk")
    value.add_argument("--expectile", type=real_in(0.0, 1.0, low_open=True, high_open=True), default=0.7, help="IQL's tau")
    vla = train.add_argument_group("vla")
    vla.add_argument("--annotations", default=None,
                     help="`seal annotate` output directory (reasoning labels), or several comma-separated: the "
                          "demonstrations first, then `seal demos dagger` rounds (OUT/annotations)")
    vla.add_argument("--mix", default=None, help="comma-separated share of each batch per --annotations directory "
                                                 "(default: in proportion to their frames)")
    vla.add_argument("--instruction-dropout", type=real_in(0.0, 1.0, high_open=True), default=None,
                     help="share of samples trained with the instruction left out, so actions read the sub-plan "
                          "(reasoning model; default 0)")
    vla.add_argument("--plan-only-actions", action=argparse.BooleanOptionalAction, default=None,
                     help="the action expert sees an empty instruction: chunks follow the sub-plan text, the cameras "
                          "and the state alone, so a reworded instruction acts only through the plan (default: "
                          "as the --init-from model, else off)")
    vla.add_argument("--text-share", type=real_in(0.0, 1.0, low_open=True, high_open=True), default=None,
                     help="with --plan-only-actions: share of ordinary samples that train the reasoning text "
                          "(default 0.25); the rest train the actions")
    vla.add_argument("--no-reasoning", action="store_true", help="train the non-reasoning twin (pi0 baseline)")
    vla.add_argument("--device", default=None, help="cpu (default) | cuda")
    vla.add_argument("--cache", default=None, help="frame cache directory (default RUN/cache; reusable across runs)")
    vla.add_argument("--bf16", action=argparse.BooleanOptionalAction, default=None,
                     help="bf16 autocast (default: on where the hardware has bf16 units, a GPU or a CPU with "
                          "avx512_bf16/AMX; emulated bf16 was ~5x slower here, docs/decisions.md)")
    vla.add_argument("--save-minutes", type=POSITIVE, default=None, help="checkpoint interval (default 10)")
    vla.add_argument("--eval-every", type=COUNT, default=None, help="held-out evaluation interval in steps (500)")
    vla.add_argument("--model-config", default=None, help="JSON file of VLAConfig fields to override")
    vla.add_argument("--export", default=None, metavar="DIR",
                     help="after training (or on a finished run), write a 16-bit copy of the checkpoint to DIR "
                          "for shipping, e.g. src/seal/policies/vla/checkpoints/reason")
    vla.add_argument("--export-dtype", default="bf16", choices=["bf16", "fp16", "fp32"])
    ver = train.add_argument_group("verifier")
    ver.add_argument("--data", default=None, help="`seal verify collect` directory, or several comma-separated "
                                                   "(e.g. a LIBERO-10 and a LIBERO-90 collection)")
    ver.add_argument("--holdout-tasks", default="",
                     help="comma-separated task keys (libero_10/1,...) never trained on")
    ver.add_argument("--holdout-inits", type=float, default=0.2,
                     help="fraction of each other task's init states held out")
    ver.add_argument("--image-size", type=int, default=96, help="model input size in pixels")
    ver.add_argument("--negative-weight", type=float, default=1.0,
                     help="loss weight of a failed case against 1 for a successful one (> 1 buys precision: a false "
                          "pass costs SEAL the episode, a refusal a round; default 1)")
    ver.add_argument("--hard-negative-weight", type=float, default=1.0,
                     help="with --init-from: failed cases the initial checkpoint passes weigh this much more again "
                          "(its confident false successes; default 1: off)")
    ver.add_argument("--jitter", type=float, default=0.0,
                     help="augmentation: brightness/contrast factors in [1-j, 1+j] per case (default 0: off)")
    ver.add_argument("--weight-decay", type=float, default=1e-4, help="AdamW weight decay (default 1e-4)")
    ver.add_argument("--lr-schedule", default="constant", choices=["constant", "cosine"],
                     help="learning rate over the run: constant, or cosine decay to 0 at --steps (default constant)")
    ver.add_argument("--ema", type=float, default=0.0,
                     help="checkpoint an exponential moving average of the weights with this decay, e.g. 0.999 "
                     "(it is also what the held-out figures score); default 0: the last weights")
    ver.add_argument("--train-seed", type=int, default=None,
                     help="seed of the initial weights, batches and augmentation (default: --seed, which also draws "
                     "the held-out split); another --train-seed on the same split measures run-to-run spread")
    ver.add_argument("--save-every-min", type=POSITIVE, default=5.0, help="minutes between checkpoints")
    ver.add_argument("--score", default=None, help="instead of training: score these checkpoint directories "
                     "(comma-separated) on the held-out splits this command's --data, --holdout-tasks, --holdout-inits "
                     "and --seed make, per split and per policy that made the cases (one JSON; --out caches images)")
    ver.add_argument("--average", default=None, metavar="RUN1,RUN2",
                     help="instead of training: write to --out one checkpoint whose weights are the mean of these "
                          "runs' (fine-tunes of one checkpoint on the same data, different --train-seed)")
    ver.add_argument("--export-heldout", action="store_true",
                     help="instead of training: write the held-out cases this command's --data, --holdout-tasks, "
                     "--holdout-inits and --seed make as collections OUT/heldout_inits and OUT/heldout_tasks, for "
                     "`seal bench verifier --data` (any verifier on the cases a learned one was held out on)")
    ver.add_argument("--export-train", action="store_true",
                     help="with --export-heldout: the rest of the split too, as OUT/train (a calibration set when "
                     "--data is a collection the verifier did not train on, e.g. another policy's cases)")
    train.set_defaults(func=_cmd_train)


@contextlib.contextmanager
def _stage_bars(names: dict[str, str], info):
    """A progress display for a training command: one bar per stage (``names``: stage -> label;
    stages not named are "training"), ``info(extra)`` the text beside it. Yields the callback
    ``progress(stage, done, total, extra=None)`` the trainers take."""
    from seal.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("{task.fields[info]}"), TimeRemainingColumn()) as bar:
        jobs: dict = {}

        def progress(stage, done, total, extra=None):
            if stage not in jobs:
                jobs[stage] = bar.add_task(names.get(stage, "training"), total=total, info="")
            bar.update(jobs[stage], completed=done, total=total, info=info(extra))

        yield progress


def _cmd_train(args) -> int:
    if args.what == "verifier":
        return _cmd_train_verifier(args)
    if args.what == "vla":
        return _cmd_train_vla(args)
    if args.init_from:
        raise InvalidInput("--init-from fine-tunes a vla or verifier checkpoint; seal train value trains from scratch")

    from seal.train.pipeline import train_value_on_dataset
    from seal.train.vgps import IQLConfig

    if not args.dataset:
        raise InvalidInput("seal train value needs --dataset (a LeRobot dataset)")
    rollouts = [Path(p.strip()) for p in (args.rollouts or "").split(",") if p.strip()]
    for path in rollouts:
        if not (path / "dataset").is_dir():
            raise InvalidInput(f"--rollouts {path}: not a `seal demos dagger` collection (no dataset/ in it)")
    given = {"steps": args.steps, "batch_size": args.batch_size, "lr": args.lr, "seed": args.seed}
    cfg = IQLConfig(gamma=args.gamma, expectile=args.expectile, **{k: v for k, v in given.items() if v is not None})
    stages = {"load": "reading episodes", "train": "IQL updates"}
    with _stage_bars(stages, lambda m: f"q_loss {m['q_loss']:.4f}" if m and "q_loss" in m else "") as progress:
        summary = train_value_on_dataset(Path(args.dataset), Path(args.out), goals=args.goals,
                                         holdout=0.2 if args.holdout is None else args.holdout, cfg=cfg,
                                         rollouts=rollouts, progress=progress)
    print(json.dumps({k: summary[k] for k in ("train_transitions", "rollout_transitions", "last", "heldout",
                                              "heldout_rollouts", "train_fit") if k in summary}))
    return 0


def _cmd_train_verifier(args) -> int:

    from seal.train.verifier import VerifierTrainConfig, train_verifier

    if args.average:
        from seal.train.verifier import average_runs

        runs = [Path(r) for r in args.average.split(",") if r.strip()]
        print(json.dumps(average_runs(runs, Path(args.out), command="seal " + " ".join(args.argv))))
        return 0
    if not args.data:
        raise InvalidInput("seal train verifier needs --data (one or more `seal verify collect` directories, "
                           "comma-separated)")
    holdout = tuple(t.strip() for t in (args.holdout_tasks or "").split(",") if t.strip())
    given = {"steps": args.steps, "batch_size": args.batch_size, "lr": args.lr, "seed": args.seed}  # None: defaults
    cfg = VerifierTrainConfig(image_size=args.image_size, holdout_tasks=holdout, holdout_inits=args.holdout_inits,
                              jitter=args.jitter, negative_weight=args.negative_weight,
                              hard_negative_weight=args.hard_negative_weight, weight_decay=args.weight_decay, lr_schedule=args.lr_schedule,
                              train_seed=args.train_seed, ema=args.ema, save_every_s=args.save_every_min * 60.0,
                              **{k: v for k, v in given.items() if v is not None})
    if args.export_heldout:
        from seal.train.verifier import export_heldout

        counts = export_heldout([Path(d) for d in args.data.split(",") if d], Path(args.out), cfg,
                                train=args.export_train)
        print(json.dumps({"out": str(Path(args.out).resolve()), "cases": counts}))
        return 0
    if args.score:
        from seal.train.verifier import score_runs

        scores = score_runs([Path(d) for d in args.data.split(",") if d], [Path(r) for r in args.score.split(",") if r],
                            cfg, cache_dir=Path(args.out) if args.out else None)
        print(json.dumps({run: {part: None if m is None else {k: v for k, v in m.items() if k != "per_kind"}
                                for part, m in res.items()} for run, res in scores.items()}))
        return 0
    with _stage_bars({"load": "decoding images", "train": "training"}, lambda info: info or "") as progress:
        summary = train_verifier([Path(d) for d in args.data.split(",") if d], Path(args.out), cfg, progress=progress,
                                 threads=1 if args.threads is None else args.threads,
                                 command="seal " + " ".join(args.argv), init_from=args.init_from)
    keys = ("step", "split", "heldout_inits", "heldout_tasks")
    print(json.dumps({k: ({m: v for m, v in summary[k].items() if m != "per_kind"} if isinstance(summary[k], dict)
                          and "per_kind" in summary[k] else summary[k]) for k in keys}))
    return 0


def _cmd_train_vla(args) -> int:
    from dataclasses import replace


    from seal.policies.vla.model import VLAConfig
    from seal.train.vla import TrainConfig, train_vla

    if not args.annotations:
        raise InvalidInput("seal train vla needs --annotations (a `seal annotate` output directory)")
    given = {"steps": args.steps, "batch_size": args.batch_size, "lr": args.lr, "holdout": args.holdout,
             "device": args.device, "threads": args.threads, "save_minutes": args.save_minutes,
             "eval_every": args.eval_every, "bf16": args.bf16, "seed": args.seed,
             "instruction_dropout": args.instruction_dropout, "text_share": args.text_share}
    cfg = replace(TrainConfig(), **{k: v for k, v in given.items() if v is not None})
    model_cfg = VLAConfig()
    if args.model_config:
        try:
            model_cfg = VLAConfig.from_dict({**model_cfg.to_dict(), **json.loads(Path(args.model_config).read_text())})
        except (OSError, json.JSONDecodeError, TypeError) as exc:
            raise InvalidInput(f"--model-config {args.model_config}: {exc}") from None
    if args.no_reasoning:
        model_cfg = replace(model_cfg, reasoning=False)
    mix = None
    if args.mix:
        try:
            mix = [float(w) for w in args.mix.split(",")]
        except ValueError:
            raise InvalidInput(f"--mix must be comma-separated numbers, one per --annotations directory; got "
                               f"{args.mix!r}") from None

    def info(m):
        return f"loss {m['loss']:.4f}  {m['samples_per_s']:.1f} samples/s" if m else ""

    with _stage_bars({"cache": "decoding episodes", "train": "training"}, info) as progress:
        summary = train_vla(Path(args.dataset) if args.dataset else None,
                            [Path(a) for a in args.annotations.split(",") if a.strip()], Path(args.out),
                            cfg, model_cfg, cache=Path(args.cache) if args.cache else None, progress=progress,
                            command="seal " + " ".join(args.argv), mix=mix, init_from=args.init_from,
                            plan_only_actions=args.plan_only_actions)
    out = {k: summary[k] for k in ("run", "step", "params", "last", "heldout")}
    if args.export:
        from seal.policies.vla.checkpoint import export_checkpoint
        from seal.policies.vla.locate import RUN_CHECKPOINT

        manifest = export_checkpoint(Path(args.out) / RUN_CHECKPOINT, Path(args.export), dtype=args.export_dtype)
        out["export"] = {"dir": args.export, "dtype": manifest["dtype"], "mb": round(manifest["weights_bytes"] / 1e6, 2)}
    print(json.dumps(out))
    return 0
