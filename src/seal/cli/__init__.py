"""The `seal` command. Thin: parse arguments, call one function, print the result."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import sys
from pathlib import Path

from seal.errors import InvalidInput, SealError
from seal.options import int_at_least, real_in


def _cmd_run(args) -> int:
    from rich.console import Console

    from seal.steer.events import ProgressReporter
    from seal.steer.method import MethodSpec
    from seal.steer.run import run_steered

    spec = MethodSpec(method=args.method, **_method_settings(args))
    console = Console(stderr=True)
    _warn_render([spec])
    title = f"{spec.method} on {args.suite}/{args.task} init {args.init} (K={spec.effective_k})"
    with console.status(title) as status:
        progress = ProgressReporter(lambda text: status.update(f"{title}: {text}"))
        result = run_steered(spec, args.suite, args.task, args.init, Path(args.out), seed=args.seed,
                             max_steps=args.max_steps, video=not args.no_video, grids=not args.no_grids,
                             subscribers=(progress,))
    keys = ("task", "method", "init_index", "success", "ended_by", "sim_error", "steps", "wall_s", "subplans",
            "goal_status", "verifier_calls", "verifier_errors", "verifier_unavailable", "rounds", "fallbacks",
            "done_checks", "divergence", "timing", "trace")
    print(json.dumps({k: getattr(result, k) for k in keys}, indent=2))
    return 0


def _warn_render(specs) -> None:
    """Say so (once per method) when a learned policy will see pixels unlike its training data."""
    for spec in specs:
        if (text := spec.render_warning()) is not None:
            print(f"seal: warning: {spec.label}: {text}", file=sys.stderr)


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


def _cmd_demos(args) -> int:
    from seal.progress import Progress

    from seal.demos import record_demos
    from seal.policies.expert.policy import FailureKnobs
    from seal.sim.suites import parse_task_ids, task_count

    tasks = None if not args.tasks else parse_task_ids(args.suite, args.tasks)
    n_tasks = task_count(args.suite) if tasks is None else len(tasks)
    with Progress() as bar:
        job = bar.add_task(f"recording {args.suite}", total=n_tasks * args.episodes_per_task)

        def progress(spec, summary, advance):
            bar.update(job, advance=advance,
                       description=f"{spec.key}: {summary.recorded} recorded, {summary.failed} failed")

        summary = record_demos(args.suite, Path(args.out), episodes_per_task=args.episodes_per_task, tasks=tasks,
                               knobs=FailureKnobs.named(args.knobs), progress=progress,
                               keep_failures=args.keep_failures, starts=args.starts, image_size=args.image_size,
                               render_mode=args.render, workers=args.workers, dart=args.dart)
    print(json.dumps(summary.__dict__))
    return 0


def _cmd_dagger(args) -> int:
    from seal.dagger import collect_dagger
    from seal.progress import Progress
    from seal.sim.suites import parse_task_ids

    tasks = None if not args.tasks else parse_task_ids(args.suite, args.tasks)
    with Progress() as bar:
        job = bar.add_task(f"DAgger round {args.round}", total=None)

        def progress(summary, total, advance):
            bar.update(job, total=total, advance=advance,
                       description=f"{summary.recorded} rollouts ({summary.successes} solved), {summary.frames} "
                                   f"labelled states, {summary.invalid_labels} without a teacher answer")

        summary = collect_dagger(args.suite, Path(args.out), ckpt=args.ckpt, episodes_per_task=args.episodes_per_task,
                                 round_=args.round, beta=args.beta, tasks=tasks, workers=args.workers,
                                 render_mode=args.render, max_steps=args.max_steps,
                                 teacher_check=args.teacher_check, verifier_cases=args.verifier_cases,
                                 progress=progress)
    print(json.dumps(summary.__dict__))
    return 0


def _cmd_dagger_report(args) -> int:
    from seal.dagger import ATTEMPTS, summarize, unrecovered_sheet

    if not (Path(args.dir) / ATTEMPTS).is_file():
        raise InvalidInput(f"{args.dir} holds no DAgger collection (no {ATTEMPTS}); give a `seal demos dagger --out` directory")
    out = summarize(Path(args.dir))
    if args.sheet:
        sheet = unrecovered_sheet(Path(args.dir), Path(args.sheet))
        out["sheet"] = str(sheet) if sheet else None
    print(json.dumps(out))
    return 0


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

    from seal.train.pipeline import train_value_on_dataset
    from seal.train.vgps import IQLConfig

    if not args.dataset:
        raise InvalidInput("seal train value needs --dataset (a LeRobot dataset)")
    given = {"steps": args.steps, "batch_size": args.batch_size, "lr": args.lr, "seed": args.seed}
    cfg = IQLConfig(gamma=args.gamma, expectile=args.expectile, **{k: v for k, v in given.items() if v is not None})
    stages = {"load": "reading episodes", "train": "IQL updates"}
    with _stage_bars(stages, lambda m: f"q_loss {m['q_loss']:.4f}" if m and "q_loss" in m else "") as progress:
        summary = train_value_on_dataset(Path(args.dataset), Path(args.out), goals=args.goals,
                                         holdout=0.2 if args.holdout is None else args.holdout, cfg=cfg,
                                         progress=progress)
    print(json.dumps({k: summary[k] for k in ("train_transitions", "last", "heldout", "train_fit") if k in summary}))
    return 0


def _cmd_verify(args) -> int:
    from seal.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from seal.collect import CollectOptions, collect
    from seal.sim.suites import parse_task_ids

    settings = {k: v for k, v in _method_settings(args).items() if k not in ("k", "rounds", "policy", "knobs")}
    given = {"k": args.k, "rounds": args.rounds}  # None: CollectOptions' own defaults
    opts = CollectOptions(suite=args.suite, tasks=parse_task_ids(args.suite, args.tasks), per_task=args.per_task,
                          policy=args.policy, knobs=args.knobs, **{k: v for k, v in given.items() if v is not None},
                          balance=args.balance, early_exit=args.early_exit, init_source=args.init_source,
                          inits_per_task=args.inits_per_task,
                          max_episodes=args.max_episodes, patience=args.patience, max_steps=args.max_steps,
                          workers=args.workers, method_settings=settings)
    try:
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TimeElapsedColumn()) as bar:
            job = bar.add_task("verification cases", total=len(opts.tasks) * opts.per_task)

            def progress(text, kept, total):
                bar.update(job, completed=total, description=text)

            summary = collect(opts, Path(args.out), progress=progress)
    except KeyboardInterrupt:  # the pool's workers ignore Ctrl-C; they were closed on the way out
        print(f"seal: interrupted: {_collection_kept(Path(args.out), opts)}", file=sys.stderr)
        return 130
    for key, why in summary["tasks_given_up"].items():
        print(f"seal: warning: {key} given up: {why}", file=sys.stderr)
    print(json.dumps(summary))
    return 0


def _collection_kept(out: Path, opts) -> str:
    """What an interrupted `seal verify collect` leaves, and how to go on."""
    from seal.collect import existing
    from seal.sim.suites import get_task

    keys = {get_task(opts.suite, t).key for t in opts.tasks}
    try:
        have = {k: v for k, v in existing(out).items() if k in keys}
    except Exception as exc:  # noqa: BLE001 - a summary line must not turn into a traceback
        return f"could not count the cases in {out} ({exc}); run the same command again to continue"
    cases = sum(v["success"] + v["failure"] for v in have.values())
    episodes = sum(len(v["episodes"]) for v in have.values())
    if not episodes:
        return f"no episode had finished, so no case was kept in {out}; run the same command again to start over"
    return (f"{out} keeps {cases} case(s) from {episodes} finished episode(s) (the episode in progress was dropped); "
            "run the same command again to continue")


def _cmd_verify_from_demos(args) -> int:
    from seal.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from seal.verify.demo_cases import DemoCaseOptions, from_demos

    try:
        fractions = tuple(float(f) for f in args.fractions.split(","))
    except ValueError:
        raise InvalidInput(f"--fractions must be comma-separated numbers in (0, 1], got {args.fractions!r}") from None
    try:
        tasks = None if args.tasks is None else [int(t) for t in args.tasks.split(",")]
    except ValueError:
        raise InvalidInput(f"--tasks must be comma-separated task ids, got {args.tasks!r}") from None
    opts = DemoCaseOptions(fractions=fractions, after=args.after, episodes_per_task=args.episodes_per_task,
                           branches=args.branches, branch_from=args.branch_from, branch_miss=args.branch_miss,
                           grip_branch=args.grip_branch, only_branches=args.only_branches)
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn()) as bar:
        job = bar.add_task("replaying demonstrations", total=None)

        def progress(done, total, text):
            bar.update(job, completed=done, total=total, description=text)

        summary = from_demos(Path(args.dataset), Path(args.out), opts, tasks=tasks, progress=progress)
    if summary["replay_failed"]:
        print(f"seal: warning: {len(summary['replay_failed'])} replay(s) did not end in success and gave no cases "
              f"(episodes {summary['replay_failed'][:10]})", file=sys.stderr)
    print(json.dumps(summary))
    return 0


def _cmd_train_verifier(args) -> int:

    from seal.train.verifier import VerifierTrainConfig, train_verifier

    if not args.data:
        raise InvalidInput("seal train verifier needs --data (one or more `seal verify collect` directories, "
                           "comma-separated)")
    holdout = tuple(t.strip() for t in (args.holdout_tasks or "").split(",") if t.strip())
    given = {"steps": args.steps, "batch_size": args.batch_size, "lr": args.lr, "seed": args.seed}  # None: defaults
    cfg = VerifierTrainConfig(image_size=args.image_size, holdout_tasks=holdout, holdout_inits=args.holdout_inits,
                              jitter=args.jitter, weight_decay=args.weight_decay, lr_schedule=args.lr_schedule,
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
                                 command="seal " + " ".join(args.argv))
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
             "instruction_dropout": args.instruction_dropout}
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
                            command="seal " + " ".join(args.argv), mix=mix, init_from=args.init_from)
    out = {k: summary[k] for k in ("run", "step", "params", "last", "heldout")}
    if args.export:
        from seal.policies.vla.checkpoint import export_checkpoint
        from seal.policies.vla.locate import RUN_CHECKPOINT

        manifest = export_checkpoint(Path(args.out) / RUN_CHECKPOINT, Path(args.export), dtype=args.export_dtype)
        out["export"] = {"dir": args.export, "dtype": manifest["dtype"], "mb": round(manifest["weights_bytes"] / 1e6, 2)}
    print(json.dumps(out))
    return 0


def _cmd_suites(args) -> int:
    from seal import suite_tools

    return suite_tools.main(args)


def _cmd_eval(args) -> int:
    from seal.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from seal.eval.execute import RunOptions
    from seal.eval.runner import run_eval
    from seal.sim.suites import parse_task_ids
    from seal.steer.method import parse_methods

    methods = parse_methods(args.methods, **_method_settings(args))
    _warn_render(methods)
    suites = [s.strip() for s in args.suite.split(",") if s.strip()]
    tasks = None
    if args.tasks:  # the same ids in every suite: each must have them
        tasks = [parse_task_ids(suite, args.tasks) for suite in suites][0]
    out = args.out or str(Path(args.db).with_suffix("")) + "_runs"
    options = RunOptions(out_dir=out, video=args.video, grids=not args.no_grids, pool_workers=args.pool_workers,
                         max_steps=args.max_steps)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    tally: dict = {}
    with Progress(*columns) as bar:
        job = bar.add_task("eval", total=None)

        def on_row(row, ran, total):
            ok, n = tally.get(row.method, (0, 0))
            tally[row.method] = (ok + row.success, n + 1)
            rates = "  ".join(f"{m} {a}/{b}" for m, (a, b) in tally.items())
            flag = " [red]error[/red]" if row.status == "error" else ""
            bar.update(job, total=total, completed=ran, description=f"{row.suite}/{row.task}  {rates}{flag}")

        summary = run_eval(args.db, methods, suites, tasks, args.trials, options=options, backend=args.backend,
                           workers=args.workers, address=args.address, on_row=on_row,
                           retry_errors=args.retry_errors)
    print(json.dumps(summary.__dict__))
    for method, n in summary.verifier_errors.items():
        if n:
            print(f"seal: warning: {method}: {n} verification(s) got no answer (verifier errors past their "
                  f"retries); {summary.verifier_unavailable[method]} trial(s) mostly unverified. See `seal report`.",
                  file=sys.stderr)
    return 0


def _cmd_report(args) -> int:
    from seal.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from seal.report import write_report

    out = args.out or str(Path(args.db).with_suffix("")) + "_report"
    with Progress(TextColumn("episode pages"), BarColumn(), MofNCompleteColumn(), transient=True) as bar:
        job = bar.add_task("pages", total=None)
        paths = write_report(args.db, out, runs_dir=args.runs, media=args.media, paper_training=args.paper_training,
                             episodes=not args.no_episodes,
                             progress=lambda done, total: bar.update(job, completed=done, total=total))
    print(json.dumps({"index": str(paths.index_html), "markdown": str(paths.markdown),
                      "csv": [str(p) for p in paths.csv], "plots": [str(p) for p in paths.plots],
                      "episode_pages": len(paths.episodes)}))
    return 0


def _cmd_serve(args) -> int:
    from dataclasses import replace

    from seal.policies import POLICIES, servable
    from seal.serving.server import PolicyServer, check_port, policy_server

    name, colon, path = args.policy.partition(":")
    served = servable()
    if name not in served or (colon and not POLICIES.options(name).checkpoint):
        valid = [v for n in served for v in ((n, f"{n}:PATH") if POLICIES.options(n).checkpoint else (n,))]
        raise InvalidInput(f"unknown --policy {args.policy!r} for seal serve; valid: {', '.join(valid)}")
    if args.max_batch < 1:
        raise InvalidInput(f"--max-batch must be >= 1, got {args.max_batch}")
    check_port(args.port)  # before a checkpoint loads; a port in use is found when the server binds
    api_key = None
    if args.require_api_key:
        api_key = os.environ.get("OPENPI_API_KEY")
        if not api_key:
            raise InvalidInput("--require-api-key: set the key in the OPENPI_API_KEY environment variable "
                               "(never on the command line)")
    options = POLICIES.options_of(name, args)  # the serve flags it declares (--knobs)
    if colon:
        options = replace(options, **{options.checkpoint: path})
    factory, info, meta, default_task = policy_server(name, options, seed=args.seed, max_batch=args.max_batch,
                                                      plain=args.plain, task=args.task)
    server = PolicyServer(factory, info, host=args.host, port=args.port, default_task=default_task, api_key=api_key,
                          metadata=meta)

    def ready(port: int) -> None:  # one JSON line on stdout: scripts (and tests) read the port from it
        print(json.dumps({"event": "listening", "url": f"ws://{args.host}:{port}", "port": port}), flush=True)

    server.serve_forever(ready)
    print(json.dumps({"event": "stopped", "requests": server.requests}), flush=True)
    return 0


def _cmd_annotate(args) -> int:
    from rich.console import Console
    from seal.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from seal.annotate.backends import make_annotator
    from seal.annotate.pipeline import (RunOptions, annotate_dataset, parse_episode_list, read_annotations,
                                        summary_dict)
    from seal.annotate.quality import quality_report
    from seal.datasets import open_dataset

    reader = open_dataset(Path(args.dataset))
    episodes = parse_episode_list(args.episodes, reader.num_episodes) if args.episodes else None
    opts = {} if args.backend == "offline" else {
        "timeout_s": args.timeout, "max_retries": args.max_retries, "max_invalid": args.max_invalid,
        "frame_stride": args.frame_stride, "cache_dir": args.cache_dir}
    annotator = make_annotator(args.backend, model=args.model, base_url=args.base_url, **opts)
    options = RunOptions(episodes=episodes, camera=args.camera, concurrency=args.concurrency,
                         videos=args.videos, retry_failed=args.retry_failed)
    console = Console(stderr=True)
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console) as bar:
        job = bar.add_task(f"annotating with {annotator.backend}:{annotator.model}", total=None)

        def on_start(todo, skipped):
            bar.update(job, total=todo, description=f"{annotator.backend}: {todo} to do, {skipped} already done")

        def progress(record, s):
            bar.update(job, advance=1, description=f"{annotator.backend}: {s.annotated} ok, {s.failed} failed, "
                                                   f"${s.cost_usd:.4f}")

        summary = annotate_dataset(reader, Path(args.out), annotator, options, progress=progress, on_start=on_start)
    result = summary_dict(summary)
    result["out"] = str(Path(args.out).resolve())
    result["quality"] = quality_report(read_annotations(Path(args.out)), reader, options.horizon)
    print(json.dumps(result))
    return 0 if summary.failed == 0 else 1


def _cmd_bench(args) -> int:
    from seal.benchmarks import run_benchmark

    print(json.dumps(run_benchmark(args.what, args)))
    return 0


# ---- the parser: one _add_<command> per sub-command --------------------------------------------
class _Parser(argparse.ArgumentParser):
    """Every bad value ends the same way: ``seal: error: ...`` on stderr and exit status 2."""

    def error(self, message: str):
        # A bad value of a known option is said in one line (what was given, what is valid); the
        # usage helps only when the command line itself is malformed (a missing or unknown option).
        if not re.match(r"argument [^:]+: (invalid|must be)", message):
            self.print_usage(sys.stderr)
        self.exit(2, f"seal: error: {message}\n")


# one definition of these argparse types, shared with the plug-ins' options (`seal.options`)
_int_at_least, _real = int_at_least, real_in
_COUNT = _int_at_least(1)  # how many (steps, trials, workers, ...)
_INDEX = _int_at_least(0)  # which one, from 0
_RATE = _real(0.0, 1.0)  # a probability or rate
_FRACTION = _real(0.0, 1.0, high_open=True)  # a share held out (1 would leave nothing)
_POSITIVE = _real(0.0, low_open=True)  # seconds, minutes, a learning rate
_NONNEGATIVE = _real(0.0)


def _method_flags(without=()) -> list:
    """The method options shared by `seal run`, `seal eval` and `seal verify collect`, generated from
    the loop's settings and every registered plug-in's options (`seal.steer.method.settings`): a
    flag per setting, its type and help (with the default) from the declaration. Defaults are None
    here (= not given), so MethodSpec's own apply and every command means the same by them."""
    from seal.steer.method import settings

    return [s for s in settings() if s.flag and s.name not in without]


def _add_method_options(p: argparse.ArgumentParser, without=()) -> None:
    group = p.add_argument_group("method options (seal.steer.method.MethodSpec)")
    for setting in _method_flags(without):
        group.add_argument(setting.option, type=setting.type, default=None, help=setting.help)


def _method_settings(args) -> dict:
    """The method options given on the command line, as MethodSpec settings."""
    return {s.name: getattr(args, s.name) for s in _method_flags() if getattr(args, s.name, None) is not None}


def _collect_fixes() -> set[str]:
    """What `seal verify collect` sets itself: the policy and the expert's knobs (its own flags),
    the verifier (the oracle labels every case) and the scorer, with their options."""
    from seal.policies import POLICIES
    from seal.steer.scoring import SCORERS
    from seal.verify import VERIFIERS

    judges = (VERIFIERS.option_names() | SCORERS.option_names()) - POLICIES.option_names()
    return {"policy", "knobs", "verifier", "scorer", "value_goal"} | judges


def _policy_help(only=None) -> str:
    """The registered policies, each with its one-line summary (``only``: a filter on the names)."""
    from seal.policies import POLICIES

    names = [n for n in POLICIES.names if only is None or only(n)]
    return " | ".join(f"{n}{'[:PATH]' if POLICIES.options(n).checkpoint else ''}: {POLICIES.plugin(n).summary}"
                      for n in names)


def _served(name: str) -> bool:
    from seal.policies import servable

    return name in servable()


def _knobs() -> tuple[str, list[str]]:
    """The scripted expert's knobs setting: its default and choices, as its options declare them."""
    from seal.policies.options import KNOBS, ScriptedOptions

    return ScriptedOptions().knobs, list(KNOBS)


def _method_choices() -> tuple[list[str], str]:
    """The registered methods and a help text naming each."""
    from seal.steer.config import METHODS

    return list(METHODS.names), " | ".join(f"{n}: {METHODS.plugin(n).summary}" for n in METHODS.names)


def _add_run(sub) -> None:
    run = sub.add_parser("run", help="one steered LIBERO episode: video, trace, candidate grids, summary")
    run.add_argument("--suite", default="libero_10")
    run.add_argument("--task", type=int, default=0)
    run.add_argument("--init", type=_INDEX, default=0, help="official init state index")
    methods, methods_help = _method_choices()
    run.add_argument("--method", default="seal", choices=methods, help=methods_help)
    run.add_argument("--max-steps", type=_COUNT, default=None, help="default: the suite's limit")
    run.add_argument("--seed", type=int, default=0)
    run.add_argument("--no-video", action="store_true")
    run.add_argument("--no-grids", action="store_true")
    run.add_argument("--out", default="runs/demo")
    _add_method_options(run)
    # the paper's background verification; --verify-order slot repeats a `seal eval` trial exactly
    run.set_defaults(func=_cmd_run, verify_order="arrival")


def _add_ground(sub) -> None:
    gr = sub.add_parser("ground", help="the goal atoms the oracle verifier checks for a sub-plan text")
    gr.add_argument("text", help='e.g. "place it in the basket"')
    gr.add_argument("--suite", default="libero_10")
    gr.add_argument("--task", type=int, default=0)
    gr.add_argument("--plan", nargs="*", default=None,
                    help="earlier sub-plans, so 'it' can be resolved (default: the expert's plan)")
    gr.set_defaults(func=_cmd_ground)


def _add_demos(sub) -> None:
    demos = sub.add_parser("demos", help="scripted-expert demonstrations as a LeRobot dataset")
    demos_sub = demos.add_subparsers(dest="demos_command", required=True)
    rec = demos_sub.add_parser("record", help="record successful expert episodes (resumable)")
    rec.add_argument("--suite", default="libero_10")
    rec.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    rec.add_argument("--episodes-per-task", type=_COUNT, default=10)
    rec.add_argument("--knobs", default="clean", choices=["clean", "misaligned"])
    rec.add_argument("--out", required=True)
    rec.add_argument("--keep-failures", action="store_true",
                     help="also write failed episodes (meta success=false), e.g. as contrast for value learning")
    rec.add_argument("--starts", default="sampled", choices=["sampled", "official"],
                     help="sampled: objects and fixtures placed afresh from seeds (training data; no official "
                          "init state); official: LIBERO's init state e for episode e (evaluation states)")
    rec.add_argument("--image-size", type=_COUNT, default=None,
                     help="render both cameras at this many px (e.g. 64 for a 64-px policy; lossless video); "
                          "default: openpi's 224-px view")
    rec.add_argument("--render", default="stock", choices=["stock", "fast"],
                     help="render model; record in the one the policy will be evaluated in")
    rec.add_argument("--workers", type=_COUNT, default=1, help="episodes recorded in parallel (one simulator each)")
    rec.add_argument("--dart", type=_NONNEGATIVE, default=0.0,
                     help="perturb each executed chunk by a Gaussian offset of this std (action units, e.g. 0.1) "
                          "and record the expert's unperturbed actions: demonstrations of recovering (DART)")
    rec.set_defaults(func=_cmd_demos)
    dag = demos_sub.add_parser("dagger", help="roll out a learned VLA on fresh starts and record the scripted "
                                              "expert's labels at every state it reaches (DAgger; resumable)")
    dag.add_argument("--ckpt", default="reason", help="the VLA to roll out: reason (shipped), or a checkpoint/run dir")
    dag.add_argument("--suite", default="libero_10")
    dag.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    dag.add_argument("--episodes-per-task", type=_COUNT, default=10)
    dag.add_argument("--round", type=_COUNT, default=1, help="DAgger round: each has starts of its own")
    dag.add_argument("--beta", type=_real(0.0, 1.0), default=0.0,
                     help="share of chunks the expert executes instead of the VLA (0: the VLA alone)")
    dag.add_argument("--render", default=None, choices=["stock", "fast"],
                     help="render model (default: the one the checkpoint was trained in)")
    dag.add_argument("--max-steps", type=_COUNT, default=None, help="step budget (default: the task's)")
    dag.add_argument("--teacher-check", action=argparse.BooleanOptionalAction, default=True,
                     help="after each rollout, let the expert finish alone from one of its states: how often the "
                          "teacher's labels lead somewhere (default on; ~10 s of physics per rollout)")
    dag.add_argument("--workers", type=_COUNT, default=1, help="episodes in parallel (one simulator each)")
    dag.add_argument("--verifier-cases", default=None, metavar="DIR",
                     help="also write verification cases from the VLA's own states here, labelled by the oracle "
                          "(its sub-plan ends, its 'task complete', held-versus-released places; for `seal train "
                          "verifier --data`). Off by default; the rollouts and the DAgger data are the same either way")
    dag.add_argument("--out", required=True)
    dag.set_defaults(func=_cmd_dagger)
    rep = demos_sub.add_parser("dagger-report", help="figures of a DAgger collection (all its episodes so far) and "
                                                     "a contact sheet of the states the expert could not finish from")
    rep.add_argument("dir", help="a `seal demos dagger` output directory")
    rep.add_argument("--sheet", default=None, metavar="PNG", help="write the contact sheet here")
    rep.set_defaults(func=_cmd_dagger_report)


def _add_train(sub) -> None:
    train = sub.add_parser("train", help="learned models: `value` (the V-GPS baseline's IQL Q-function), `vla` "
                                         "(the reasoning VLA or, with --no-reasoning, its pi0 twin), `verifier` "
                                         "(the learned verifier, docs/verifier.md)")
    train.add_argument("what", choices=["value", "vla", "verifier"])
    train.add_argument("--dataset", default=None,
                       help="LeRobot dataset (value: required; vla: default the one the annotations name)")
    train.add_argument("--out", required=True, help="run directory (re-running continues from its checkpoint)")
    train.add_argument("--steps", type=_COUNT, default=None, help="gradient updates (value 3000, vla 9000, verifier 2000)")
    train.add_argument("--batch-size", "--batch", dest="batch_size", type=_COUNT, default=None,
                       help="value 128, vla 32, verifier 64")
    train.add_argument("--lr", type=_POSITIVE, default=None, help="value 3e-4, vla 3e-4 (cosine decay), verifier 1e-3")
    train.add_argument("--holdout", type=_FRACTION, default=None,
                       help="fraction of episodes held out for the check (value 0.2, vla 0.1)")
    train.add_argument("--seed", type=int, default=None)
    train.add_argument("--threads", type=_COUNT, default=None, help="vla/verifier: torch threads (default 1)")
    value = train.add_argument_group("value")
    value.add_argument("--goals", default="both", choices=["task", "subplan", "both"],
                       help="goal texts to condition on: the task instruction, each sub-plan, or both")
    value.add_argument("--gamma", type=_RATE, default=0.9, help="discount per 5-step chunk")
    value.add_argument("--expectile", type=_real(0.0, 1.0, low_open=True, high_open=True), default=0.7, help="IQL's tau")
    vla = train.add_argument_group("vla")
    vla.add_argument("--annotations", default=None,
                     help="`seal annotate` output directory (reasoning labels), or several comma-separated: the "
                          "demonstrations first, then `seal demos dagger` rounds (OUT/annotations)")
    vla.add_argument("--mix", default=None, help="comma-separated share of each batch per --annotations directory "
                                                 "(default: in proportion to their frames)")
    vla.add_argument("--init-from", default=None, metavar="CKPT",
                     help="fine-tune this VLA checkpoint (reason, twin, or a directory): its shape, tokenizer and "
                          "normalization; --model-config is ignored")
    vla.add_argument("--instruction-dropout", type=_real(0.0, 1.0, high_open=True), default=None,
                     help="share of samples trained with the instruction left out, so actions read the sub-plan "
                          "(reasoning model; default 0)")
    vla.add_argument("--no-reasoning", action="store_true", help="train the non-reasoning twin (pi0 baseline)")
    vla.add_argument("--device", default=None, help="cpu (default) | cuda")
    vla.add_argument("--cache", default=None, help="frame cache directory (default RUN/cache; reusable across runs)")
    vla.add_argument("--bf16", action=argparse.BooleanOptionalAction, default=None,
                     help="bf16 autocast (default: on where the hardware has bf16 units, a GPU or a CPU with "
                          "avx512_bf16/AMX; emulated bf16 was ~5x slower here, docs/decisions.md)")
    vla.add_argument("--save-minutes", type=_POSITIVE, default=None, help="checkpoint interval (default 10)")
    vla.add_argument("--eval-every", type=_COUNT, default=None, help="held-out evaluation interval in steps (500)")
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
    ver.add_argument("--save-every-min", type=_POSITIVE, default=5.0, help="minutes between checkpoints")
    ver.add_argument("--score", default=None, help="instead of training: score these checkpoint directories "
                     "(comma-separated) on the held-out splits this command's --data, --holdout-tasks, --holdout-inits "
                     "and --seed make, per split and per policy that made the cases (one JSON; --out caches images)")
    ver.add_argument("--export-heldout", action="store_true",
                     help="instead of training: write the held-out cases this command's --data, --holdout-tasks, "
                     "--holdout-inits and --seed make as collections OUT/heldout_inits and OUT/heldout_tasks, for "
                     "`seal bench verifier --data` (any verifier on the cases a learned one was held out on)")
    ver.add_argument("--export-train", action="store_true",
                     help="with --export-heldout: the rest of the split too, as OUT/train (a calibration set when "
                     "--data is a collection the verifier did not train on, e.g. another policy's cases)")
    train.set_defaults(func=_cmd_train)


def _add_verify(sub) -> None:
    verify = sub.add_parser("verify", help="verifier data: `collect` verification cases from SEAL rounds, "
                            "or `from-demos` from recorded demonstrations")
    verify_sub = verify.add_subparsers(dest="verify_command", required=True)
    col = verify_sub.add_parser("collect", help="every candidate SEAL sends to the verifier, with its three views "
                                "and the oracle's label, as parquet (resumable; docs/verifier.md)")
    col.add_argument("--suite", default="libero_10")
    col.add_argument("--tasks", default="0", help="comma-separated task ids")
    col.add_argument("--policy", default="scripted", help="who proposes candidates: " + _policy_help())
    col.add_argument("--knobs", default=_knobs()[0], choices=_knobs()[1], help="scripted expert's failure setting")
    col.add_argument("--per-task", type=_COUNT, default=100, help="cases kept per task")
    col.add_argument("--balance", action="store_true", help="keep as many failures as successes per task")
    col.add_argument("--early-exit", action="store_true",
                     help="SEAL's early exit: a round's other candidates stop at the first pass and are never "
                          "judged (default: every candidate of a round runs to its end and becomes a case)")
    col.add_argument("--init-source", default="fresh-train", choices=["fresh-train", "fresh-heldout", "official"],
                     help="init states: fresh ones drawn for training (default), the held-out fresh range, "
                          "or LIBERO's official evaluation ones")
    col.add_argument("--inits-per-task", type=_COUNT, default=20, help="fresh init states drawn per task")
    col.add_argument("--max-episodes", type=_COUNT, default=None, help="per task (default 4 x --per-task)")
    col.add_argument("--patience", type=_COUNT, default=20,
                     help="give a task up after this many episodes in a row that kept no case (default 20)")
    col.add_argument("--max-steps", type=_COUNT, default=None, help="per episode (default: the suite's limit)")
    col.add_argument("--workers", type=_COUNT, default=None, help="simulator processes (default: min(K, cores))")
    col.add_argument("--out", required=True, help="collection directory (re-run with the same one to continue)")
    _add_method_options(col, without=_collect_fixes())
    col.set_defaults(func=_cmd_verify)
    dem = verify_sub.add_parser("from-demos", help="cases from recorded demonstrations: replay each, stop along every "
                                "sub-plan (the hard negatives: almost there), label by the oracle (training data only)")
    dem.add_argument("--dataset", required=True, help="a `seal demos record` dataset (sampled starts)")
    dem.add_argument("--tasks", default=None, help="comma-separated task ids (default: every task in the dataset)")
    dem.add_argument("--episodes-per-task", type=_COUNT, default=None, help="the first N episodes of each task")
    dem.add_argument("--fractions", default="0.3,0.6,0.8,0.9,1.0",
                     help="end states judged per sub-plan, as fractions of the way from its start to its end")
    dem.add_argument("--after", type=int, default=10, help="one more end state this many frames past the "
                     "sub-plan's end (0: none)")
    dem.add_argument("--branches", type=int, default=0, help="near misses: per sub-plan, this many replays that "
                     "leave the recording with a horizontal offset and are judged past the sub-plan's end (default 0)")
    dem.add_argument("--branch-from", type=float, default=0.5,
                     help="where a branch leaves the recording, as a fraction of the sub-plan (default 0.5)")
    dem.add_argument("--branch-miss", type=float, default=0.05,
                     help="how far (metres) a branch's hand ends from the demonstration's (default 0.05)")
    dem.add_argument("--grip-branch", action="store_true",
                     help="near misses: per sub-plan, one more replay from its start with the gripper held as it "
                     "began (a pick lifts an empty hand, a place never lets go), judged past the sub-plan's end")
    dem.add_argument("--only-branches", action="store_true",
                     help="write the branch cases alone, not the recording's own states (to add near misses to a "
                     "collection of the same demonstrations made without them)")
    dem.add_argument("--out", required=True, help="collection directory (re-run with the same one to continue)")
    dem.set_defaults(func=_cmd_verify_from_demos)


def _add_suites(sub) -> None:
    suites = sub.add_parser("suites", help="evaluation suites: list, contact sheet, generate data, check")
    suites_sub = suites.add_subparsers(dest="suites_command", required=True)
    s_list = suites_sub.add_parser("list", help="suites, task counts, instructions and what each variant changes")
    s_list.add_argument("suite", nargs="?", default=None, help="one suite (default: all)")
    s_show = suites_sub.add_parser("show", help="contact sheet of every task's first frame (agent view)")
    s_show.add_argument("suite")
    s_show.add_argument("--out", required=True, help="PNG file")
    s_show.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    s_show.add_argument("--init", type=_INDEX, default=0, help="init state index of the frames")
    s_gen = suites_sub.add_parser("generate", help="(re)write a derived suite's BDDL files and init states")
    s_gen.add_argument("suite")
    s_gen.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    s_gen.add_argument("--n", type=_COUNT, default=50, help="init states per task")
    s_gen.add_argument("--force", action="store_true", help="regenerate init states that are already current")
    s_chk = suites_sub.add_parser("check", help="build each task's world, render its first frame, check its data")
    s_chk.add_argument("suite")
    s_chk.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    s_chk.add_argument("--inits", type=_COUNT, default=5, help="init states per task to check (spread over all)")
    suites.set_defaults(func=_cmd_suites)


def _add_eval(sub) -> None:
    ev = sub.add_parser("eval", help="methods x suites x tasks x trials into a SQLite results store (resumable)")
    ev.add_argument("--suite", default="libero_10", help="comma-separated suites")
    ev.add_argument("--methods", default="base,seal",
                    help="comma-separated methods, each optionally with settings: seal:k=5:rounds=1 (a mismatch "
                         "inside an item: seal:mismatch=1.3/0.8/1.2); the method options below apply to all")
    ev.add_argument("--tasks", default="", help="comma-separated task ids (default: all)")
    ev.add_argument("--trials", type=_COUNT, default=50, help="trials per task (init state = trial mod #inits)")
    ev.add_argument("--db", required=True, help="results database (created if missing, resumed if present)")
    ev.add_argument("--out", default=None, help="traces/videos directory (default: next to the database)")
    ev.add_argument("--backend", default="local", help="local | ray")
    ev.add_argument("--address", default=None, help="ray: cluster address (default: start a local one)")
    ev.add_argument("--workers", type=_COUNT, default=1, help="trials run in parallel")
    ev.add_argument("--pool-workers", type=_COUNT, default=1, help="simulator processes per trial worker")
    ev.add_argument("--video", default="failures", choices=["none", "failures", "all"])
    ev.add_argument("--no-grids", action="store_true")
    ev.add_argument("--max-steps", type=_COUNT, default=None, help="cap episode length (default: the suite's)")
    ev.add_argument("--retry-errors", action="store_true",
                    help="run again the trials of this command stored as errors (a crashed worker, a server that "
                    "timed out); each error row stays until its new result replaces it")
    _add_method_options(ev)
    ev.set_defaults(func=_cmd_eval)


def _add_report(sub) -> None:
    rep = sub.add_parser("report", help="Markdown/CSV tables, plots and an HTML report from a results database")
    rep.add_argument("db", help="results database written by `seal eval`")
    rep.add_argument("--out", default=None, help="report directory (default: <db without suffix>_report)")
    rep.add_argument("--runs", default=None, help="trial files directory if moved (default: stored paths, "
                     "then <db without suffix>_runs)")
    rep.add_argument("--media", default="copy", choices=["copy", "link", "none"],
                     help="videos and grids: copy into the report, link relatively, or leave out")
    rep.add_argument("--paper-training", default="libero_100",
                     help="the paper's training set shown beside ours: libero_10 | libero_100 | libero_100_basket")
    rep.add_argument("--no-episodes", action="store_true", help="skip the per-episode pages")
    rep.set_defaults(func=_cmd_report)


def _add_serve(sub) -> None:
    serve = sub.add_parser("serve", help="serve a SEAL policy over openpi's websocket protocol (docs/serving.md)")
    serve.add_argument("--policy", default="scripted", help=_policy_help(_served) + " (default scripted)")
    serve.add_argument("--knobs", default=_knobs()[0], choices=_knobs()[1], help="scripted only")
    serve.add_argument("--host", default="127.0.0.1", help="0.0.0.0 to accept other machines")
    serve.add_argument("--port", type=int, default=8000, help="0: any free port (printed on stdout)")
    serve.add_argument("--task", default="", help="scripted: task for clients that do not configure one, e.g. "
                                                  "libero_10/0 (vla needs none)")
    serve.add_argument("--max-batch", type=int, default=64, help="largest batched request accepted")
    serve.add_argument("--seed", type=int, default=0)
    serve.add_argument("--plain", action="store_true",
                       help="answer like a plain pi0 server: actions only, no reasoning, think or batching")
    serve.add_argument("--require-api-key", action="store_true",
                       help="refuse handshakes without 'Authorization: Api-Key $OPENPI_API_KEY' (/healthz stays open)")
    serve.set_defaults(func=_cmd_serve)


def _add_annotate(sub) -> None:
    ann = sub.add_parser("annotate", help="reasoning labels for a LeRobot dataset (resumable; prints a JSON summary)")
    ann.add_argument("dataset", help="LeRobot dataset directory (v2.1 or v3.0 layout)")
    ann.add_argument("--backend", required=True, choices=["gemini", "openai", "offline"])
    ann.add_argument("--out", required=True, help="sidecar output directory (re-run with the same one to resume)")
    ann.add_argument("--episodes", default="", help="e.g. 0,3,5-9 (default: all)")
    ann.add_argument("--model", default=None, help="default: gemini-2.5-pro / gpt-4o")
    ann.add_argument("--base-url", default=None, help="server URL (default: the SDK's, e.g. OPENAI_BASE_URL)")
    ann.add_argument("--camera", default=None, help="image feature to annotate (default: the agent view)")
    ann.add_argument("--concurrency", type=_COUNT, default=4, help="episodes in flight at once")
    ann.add_argument("--timeout", type=_POSITIVE, default=180.0, help="seconds per model call attempt")
    ann.add_argument("--max-retries", type=_INDEX, default=3, help="retries of a call on 429/5xx/timeouts")
    ann.add_argument("--max-invalid", type=_INDEX, default=2, help="re-asks after a reply that fails validation")
    ann.add_argument("--frame-stride", type=_COUNT, default=1, help="openai: send every n-th 10 fps frame")
    ann.add_argument("--cache-dir", default=None, help="cache valid model answers here")
    ann.add_argument("--videos", action=argparse.BooleanOptionalAction, default=None,
                     help="write the 10 fps clips into OUT/videos (default: for model backends)")
    ann.add_argument("--retry-failed", action="store_true", help="also redo episodes that failed before")
    ann.set_defaults(func=_cmd_annotate)


def _add_bench(sub) -> None:
    bench = sub.add_parser("bench", help="benchmarks; each prints one JSON object")
    bench.add_argument("what", choices=["sim", "expert", "steer", "runtime", "eval", "serve", "annotate",
                                                       "value", "verifier", "verifier-sweep", "vla", "render"])
    bench.add_argument("--ckpt", default=None, help="vla: checkpoint (default: a random-init model of the default "
                                                     "config; 'reason'/'twin': the shipped ones)")
    bench.add_argument("--annotations", default=None, help="vla: annotations for the held-out figures")
    bench.add_argument("--size", default=None, help="vla without --ckpt: a size preset (S, M = default, L, M-p8, "
                                                     "M-e192x3)")
    bench.add_argument("--sizes", default=None, help="vla: also time training steps of these presets (e.g. S,M,L)")
    bench.add_argument("--dataset", default=None, help="annotate/value/vla: LeRobot dataset directory")
    bench.add_argument("--steps", type=_COUNT, default=None, help="value: training updates on --dataset (default 300)")
    bench.add_argument("--backend", default="offline", choices=["offline", "gemini", "openai"],
                       help="annotate: annotation backend")
    bench.add_argument("--model", default=None, help="annotate/verifier: model name (gemini/openai)")
    bench.add_argument("--base-url", default=None, help="annotate/verifier: model server URL")
    bench.add_argument("--ks", default="", help="runtime: comma-separated K values (default 1,2,4,8,10)")
    bench.add_argument("--latency", type=_NONNEGATIVE, default=2.0, help="runtime: fixed verifier latency in seconds")
    bench.add_argument("--policy", default=None,
                       help="runtime: scripted (state only), pixels (the expert reading both cameras every chunk, "
                            "a VLA's rendering without its network) or vla[:PATH]; steer/verifier-sweep: the policy "
                            "(default scripted)")
    bench.add_argument("--image-size", type=_COUNT, default=None, help="runtime: camera px for pixel policies (64); render: the size measured (64)")
    bench.add_argument("--render", default=None, choices=["stock", "fast"],
                       help="runtime: render model (default: fast for pixel policies)")
    bench.add_argument("--plot", default=None, help="runtime: write the stacked breakdown against K to this PNG")
    bench.add_argument("--dart", type=_NONNEGATIVE, default=0.0,
                       help="expert: perturb every executed chunk by a Gaussian offset of this std (as `seal demos "
                            "record --dart` does): how much perturbation the expert survives")
    bench.add_argument("--record-reference", action="store_true",
                       help="vla with --ckpt: write this machine's reference rollout (an action digest) into the "
                            "checkpoint's manifest; without it the bench reports whether this machine reproduces it")
    bench.add_argument("--round-log", default=None, metavar="ROUNDS.jsonl",
                       help="vla --rollouts: append the held-out figures to this log as --round-name and redraw "
                            "ROUNDS.png (success, on-policy sub-plan accuracy, alignment per DAgger round)")
    bench.add_argument("--round-name", default=None, help="vla --round-log: the round's label (default: the checkpoint)")
    bench.add_argument("--rollouts", type=_INDEX, default=0,
                       help="vla with --ckpt: closed-loop episodes per task on fresh sampled starts (default 0: none)")
    bench.add_argument("--tasks", default="", help="comma-separated task ids (expert: all; steer: 0,1,7; runtime: 5; render: 0,3,9)")
    bench.add_argument("--trials", type=_COUNT, default=None,
                       help="expert/steer/runtime: trials (init states) per task (default 50); eval: trials per "
                            "task (default 3); serve: round trips (default 50)")
    bench.add_argument("--max-steps", type=_COUNT, default=None,
                       help="steer/runtime/eval: control steps per episode (default: the suite's limit)")
    bench.add_argument("--no-misaligned", action="store_true", help="expert: skip the misaligned setting")
    bench.add_argument("--first-init", type=_INDEX, default=0,
                       help="expert: first official init state (trials run first-init .. first-init+trials-1)")
    bench.add_argument("--log", default=None,
                       help="expert: JSONL file, one row per finished episode; re-running resumes from it")
    bench.add_argument("--suite", default="libero_10")
    bench.add_argument("--task", type=_INDEX, default=0)
    bench.add_argument("--k", type=_COUNT, default=10)
    bench.add_argument("--workers", type=_COUNT, default=None)
    vb = bench.add_argument_group("verifier / verifier-sweep (docs/verifier.md)")
    vb.add_argument("--verifier", default="oracle",
                    help="verifier: oracle | openai | gemini | noisy | learned[:RUN_DIR]; steer: the verifier SEAL uses")
    vb.add_argument("--data", default=None, help="verifier: `seal verify collect` directory (default: a small "
                    "fresh held-out set, collected once into runs/verifier/heldout/)")
    vb.add_argument("--out", default=None, help="verifier: Markdown file; verifier-sweep: results directory "
                    "(default runs/verifier/sweep)")
    vb.add_argument("--limit", type=_COUNT, default=None, help="verifier: score at most N cases (a fixed shuffle)")
    vb.add_argument("--false-positive", type=_RATE, default=None, help="verifier noisy: false-positive rate")
    vb.add_argument("--false-negative", type=_RATE, default=None, help="verifier noisy: false-negative rate")
    vb.add_argument("--threshold", type=_RATE, default=None,
                    help="verifier learned: success when P(success) >= this (default: the checkpoint's)")
    vb.add_argument("--min-precision", type=_RATE, default=None,
                    help="verifier learned: also report the lowest threshold reaching this precision on --data "
                         "(pick it on a calibration set, report with --threshold on another)")
    vb.add_argument("--cache-dir", default=None,
                    help="verifier openai/gemini: answer cache (default ~/.cache/seal/verifier-answers)")
    vb.add_argument("--fp", default=None, help="verifier-sweep: false-positive rates (default 0,0.1,0.2,0.4)")
    vb.add_argument("--fn", default=None, help="verifier-sweep: false-negative rates (default 0,0.2,0.4)")
    vb.add_argument("--points", default=None,
                    help="verifier-sweep: comma-separated `seal bench verifier` JSON files to draw as measured points")
    bench.set_defaults(func=_cmd_bench)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="seal", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    for add in (_add_run, _add_ground, _add_demos, _add_train, _add_verify, _add_suites, _add_eval, _add_report,
                _add_serve, _add_annotate, _add_bench):
        add(sub)
    return p


def _terminate(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM cleans up like Ctrl-C: workers stopped, files closed


def main(argv: list[str] | None = None) -> int:
    import signal

    args = build_parser().parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # the command as typed (run manifests)
    signal.signal(signal.SIGTERM, _terminate)
    try:
        return args.func(args)
    except SealError as exc:
        print(f"seal: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("seal: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
