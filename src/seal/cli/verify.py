"""`seal verify collect|from-demos`: verification cases from SEAL rounds or from demonstrations."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from seal.cli.common import COUNT, add_method_options, method_settings, policy_help, scripted_knobs
from seal.errors import InvalidInput


def add(sub) -> None:
    verify = sub.add_parser("verify", help="verifier data: `collect` verification cases from SEAL rounds, "
                            "or `from-demos` from recorded demonstrations")
    verify_sub = verify.add_subparsers(dest="verify_command", required=True)
    col = verify_sub.add_parser("collect", help="every candidate SEAL sends to the verifier, with its three views "
                                "and the oracle's label, as parquet (resumable; docs/verifier.md)")
    col.add_argument("--suite", default="libero_10")
    col.add_argument("--tasks", default="0", help="comma-separated task ids")
    col.add_argument("--policy", default="scripted", help="who proposes candidates: " + policy_help())
    col.add_argument("--knobs", default=scripted_knobs()[0], choices=scripted_knobs()[1],
                     help="scripted expert's failure setting")
    col.add_argument("--per-task", type=COUNT, default=100, help="cases kept per task")
    col.add_argument("--balance", action="store_true", help="keep as many failures as successes per task")
    col.add_argument("--early-exit", action="store_true",
                     help="SEAL's early exit: a round's other candidates stop at the first pass and are never "
                          "judged (default: every candidate of a round runs to its end and becomes a case)")
    col.add_argument("--init-source", default="fresh-train", choices=["fresh-train", "fresh-heldout", "official"],
                     help="init states: fresh ones drawn for training (default), the held-out fresh range, "
                          "or LIBERO's official evaluation ones")
    col.add_argument("--inits-per-task", type=COUNT, default=20, help="fresh init states drawn per task")
    col.add_argument("--max-episodes", type=COUNT, default=None, help="per task (default 4 x --per-task)")
    col.add_argument("--patience", type=COUNT, default=20,
                     help="give a task up after this many episodes in a row that kept no case (default 20)")
    col.add_argument("--max-steps", type=COUNT, default=None, help="per episode (default: the suite's limit)")
    col.add_argument("--workers", type=COUNT, default=None, help="simulator processes (default: min(K, cores))")
    col.add_argument("--out", required=True, help="collection directory (re-run with the same one to continue)")
    add_method_options(col, without=_collect_fixes())
    col.set_defaults(func=_cmd_verify)
    dem = verify_sub.add_parser("from-demos", help="cases from recorded demonstrations: replay each, stop along every "
                                "sub-plan (the hard negatives: almost there), label by the oracle (training data only)")
    dem.add_argument("--dataset", required=True, help="a `seal demos record` dataset (sampled starts)")
    dem.add_argument("--tasks", default=None, help="comma-separated task ids (default: every task in the dataset)")
    dem.add_argument("--episodes-per-task", type=COUNT, default=None, help="the first N episodes of each task "
                     "(after any skipped)")
    dem.add_argument("--skip-episodes-per-task", type=int, default=0, help="skip each task's first N episodes: "
                     "cases from demonstrations a training collection made with --episodes-per-task N did not use "
                     "(a held-out set; default 0)")
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
    dem.add_argument("--replay-stored", action="store_true",
                     help="replay the stored float32 actions instead of re-running the expert for its exact ones "
                     "(the behaviour of collections made before 2026-12-04; about 1 in 10 such replays drifts "
                     "and fails)")
    dem.add_argument("--task-cases", action="store_true",
                     help="task-level cases (the question SEAL asks when a policy says the task is done): the "
                     "instruction judged at every sub-plan's end and at the last frame, by the task's goal")
    dem.add_argument("--only-branches", action="store_true",
                     help="write the branch cases alone, not the recording's own states (to add near misses to a "
                     "collection of the same demonstrations made without them)")
    dem.add_argument("--out", required=True, help="collection directory (re-run with the same one to continue)")
    dem.set_defaults(func=_cmd_verify_from_demos)


def _collect_fixes() -> set[str]:
    """What `seal verify collect` sets itself: the policy and the expert's knobs (its own flags),
    the verifier (the oracle labels every case) and the scorer, with their options."""
    from seal.policies import POLICIES
    from seal.steer.scoring import SCORERS
    from seal.verify import VERIFIERS

    judges = (VERIFIERS.option_names() | SCORERS.option_names()) - POLICIES.option_names()
    return {"policy", "knobs", "verifier", "scorer", "value_goal"} | judges


def _cmd_verify(args) -> int:
    from seal.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from seal.collect import CollectOptions, collect
    from seal.sim.suites import parse_task_ids

    settings = {k: v for k, v in method_settings(args).items() if k not in ("k", "rounds", "policy", "knobs")}
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

    from seal.demos import exact_actions
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
                           skip_per_task=args.skip_episodes_per_task,
                           branches=args.branches, branch_from=args.branch_from, branch_miss=args.branch_miss,
                           grip_branch=args.grip_branch, only_branches=args.only_branches,
                           task_cases=args.task_cases, rerun_expert=not args.replay_stored)
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn()) as bar:
        job = bar.add_task("replaying demonstrations", total=None)

        def progress(done, total, text):
            bar.update(job, completed=done, total=total, description=text)

        summary = from_demos(Path(args.dataset), Path(args.out), opts, tasks=tasks, progress=progress,
                             exact_actions=exact_actions)
    if summary["replay_failed"]:
        print(f"seal: warning: {len(summary['replay_failed'])} replay(s) did not end in success and gave no cases "
              f"(episodes {summary['replay_failed'][:10]})", file=sys.stderr)
    print(json.dumps(summary))
    return 0
