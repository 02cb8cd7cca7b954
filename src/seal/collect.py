"""`seal verify collect`: verification cases from real SEAL rounds (layout: `seal.verify.dataset`).

Episodes are built by `seal.steer.build.build_episode`, the same as `seal run` and `seal eval`;
the steering loop's own candidates are the cases. The loop's verifier is the oracle, made to
ask for images: the loop then renders the three views for every candidate it sends to the
verifier, and publishes each `VerifyRequest` as a ``verify_request`` event just before judging
it. `CaseRecorder` listens to that event and labels the request with the oracle; the oracle also
picks SEAL's winners, so the episode runs as SEAL with a perfect verifier would. By default a
round runs until all its candidates have ended (`WholeRounds`: no early exit), so every
candidate becomes a case; with SEAL's early exit (``early_exit=True``) the candidates still
running at the first pass are stopped and never judged, which leaves few cases per round and
fewer failures.

Init states: ``official`` uses LIBERO's evaluation starts (init index = episode mod their
count). ``fresh-train`` and ``fresh-heldout`` draw new ones the way the derived suites drew
theirs (`seal.sim.generate`: LIBERO's placement samplers, seeded, checked for a scene at rest),
from seed ranges that no shipped init state uses: ``task_seed + 100000 + j`` for training data
and ``task_seed + 200000 + j`` for the held-out set `seal bench verifier` scores without
``--data``. They are stored with the cases (``init_states/``) and reused on resume.

Resume: each episode's cases are one shard, renamed into place when the episode is over; a
re-run reads the shards back, counts what it has per task and label, and continues with the next
episode. An interrupted run loses at most the episode in progress.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from seal.errors import InvalidInput
from seal.verify import dataset as ds
from seal.steer.selection import SealSelection
from seal.verify.oracle import OracleVerifier

INIT_SOURCES = ("fresh-train", "fresh-heldout", "official")
FRESH_SEED_OFFSET = {"fresh-train": 100_000, "fresh-heldout": 200_000}


class WholeRounds(SealSelection):
    """SEAL's selection without the early exit: a round ends when all its candidates have, so every
    candidate reaches the verifier (as it does when verdicts take longer than the rollouts, the
    usual case with a VLM). The winner is still the first candidate to pass."""

    def early_winner(self, cands):
        return super().early_winner(cands) if all(c.ended_by for c in cands) else None


class ImagesOracle(OracleVerifier):
    """The oracle, asking the loop for the views a VLM would get (so they can be recorded)."""

    name = "oracle"
    needs_images = True


@dataclass
class CollectOptions:
    suite: str
    tasks: list[int]
    per_task: int = 100  # cases kept per task
    policy: str = "scripted"
    knobs: str = "misaligned"
    k: int = 10
    rounds: int = 2
    balance: bool = False  # keep as many failures as successes per task (per_task / 2 each)
    early_exit: bool = False  # SEAL's early exit: stop a round's other candidates at the first pass
    init_source: str = "fresh-train"
    inits_per_task: int = 20  # fresh sources: init states drawn per task (episodes cycle through them)
    max_episodes: int | None = None  # per task; default 4 * per_task
    # a task gives up after this many episodes in a row that kept no case: with --balance, a task whose
    # only sub-plan's success ends the task never yields a judged success, and would run max_episodes
    patience: int = 20
    max_steps: int | None = None  # per episode; default the suite's limit
    workers: int | None = None  # pool worker processes
    method_settings: dict = field(default_factory=dict)  # other MethodSpec fields (host, port, ...)

    def __post_init__(self) -> None:
        self.check()

    def check(self) -> None:
        """Refuse what cannot be collected, before anything is drawn or written; never replace a
        value given by another."""
        if self.init_source not in INIT_SOURCES:
            raise InvalidInput(f"unknown init source {self.init_source!r}; valid: {', '.join(INIT_SOURCES)}")
        counts = {"--per-task": self.per_task, "--k": self.k, "--rounds": self.rounds,
                  "--inits-per-task": self.inits_per_task, "--patience": self.patience,
                  "--max-episodes": self.max_episodes, "--max-steps": self.max_steps, "--workers": self.workers}
        optional = ("--max-episodes", "--max-steps", "--workers")  # None: the default
        for flag, value in counts.items():
            if value is None and flag in optional:
                continue
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InvalidInput(f"{flag} must be an integer >= 1, got {value!r}")
        if self.workers is not None and self.workers > self.k:
            raise InvalidInput(f"--workers must be in 1..{self.k} (one simulator serves at least one of the "
                               f"--k {self.k} candidates), got {self.workers}")

    def settings(self) -> dict:
        """What must not change between a collection and its resumption."""
        return {"suite": self.suite, "policy": self.policy, "knobs": self.knobs, "k": self.k, "rounds": self.rounds,
                "init_source": self.init_source, "balance": self.balance, "max_steps": self.max_steps,
                "early_exit": self.early_exit}


class CaseRecorder:
    """Steering-loop subscriber: every ``verify_request`` becomes a labelled case row."""

    def __init__(self, base: dict):
        self.base = base  # the episode's columns (task, init, seed, policy...)
        self.rows: list[dict] = []
        self.unknown = 0  # requests the oracle could not ground (no label, not kept)
        self._oracle = OracleVerifier()
        self._subplan_number = 0

    def on_event(self, event: str, fields: dict) -> None:
        if event == "subplan":
            self._subplan_number += 1
        if event != "verify_request":
            return
        req = fields["request"]
        verdict = self._oracle.judge(req)
        if verdict.success is None:
            self.unknown += 1
            return
        images = (req.first_agent, req.final_agent, req.final_wrist)
        for name, img in zip(ds.IMAGE_COLUMNS, images):
            if img is None or img.shape != (ds.IMAGE_SIZE, ds.IMAGE_SIZE, 3):
                raise InvalidInput(f"the loop gave no {ds.IMAGE_SIZE}px {name} image for a verification "
                                   f"(got {None if img is None else img.shape})")
        b = self.base
        case_id = (f"{b['task']}:{b['init_source']}:{b['init_index']}:e{b['episode']}:s{self._subplan_number}"
                   f":r{fields['round']}:c{fields['slot']}:{fields['steps']}")
        self.rows.append(ds.case_row(b, req, verdict, case_id=case_id, subplan_number=self._subplan_number,
                                     round=fields["round"], candidate=fields["slot"], steps=fields["steps"],
                                     ended_by=fields["ended_by"]))


# ---- init states -----------------------------------------------------------------------------------
def fresh_init_states(task, source: str, n: int, root: Path, progress: Callable | None = None):
    """(TaskSpec reading these states, their draw seeds): ``n`` fresh init states of ``task``,
    drawn once and kept under ``root/init_states``. Draws are deterministic, so state j is the
    same whatever ``n`` is."""
    from seal.sim import generate
    from seal.sim.start_check import check_state
    from seal.sim.world import LiberoWorld

    path = Path(root) / "init_states" / f"{task.suite}-{task.task_id:03d}-{source}-{n}.npz"
    if not path.is_file():
        first = generate.task_seed(task) + FRESH_SEED_OFFSET[source]
        world = LiberoWorld(task)
        try:
            states, seeds, seed = [], [], first
            while len(states) < n:
                if seed - first >= generate.MAX_DRAWS + n:
                    raise InvalidInput(f"{task.key}: only {len(states)} usable fresh init states in {seed - first} draws")
                state = world.draw_state(seed)
                if state is not None and not check_state(world, state):
                    states.append(state)
                    seeds.append(seed)
                    if progress is not None:
                        progress(len(states), n)
                seed += 1
        finally:
            world.close()
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name("." + path.name)
        with open(tmp, "wb") as f:
            np.savez_compressed(f, states=np.stack(states), seeds=np.array(seeds, dtype=np.int64))
        tmp.replace(path)
    with np.load(path) as f:
        seeds = f["seeds"]
    return dataclasses.replace(task, init_states_path=path), seeds


# ---- the collection --------------------------------------------------------------------------------
def _episode_seed(task_key: str, source: str, episode: int) -> int:
    return int.from_bytes(hashlib.sha1(f"{task_key}/{source}/{episode}".encode()).digest()[:4], "little")


def existing(root: Path) -> dict[str, dict]:
    """task key -> {"episodes": set, "success": n, "failure": n} from the shards on disk."""
    out: dict[str, dict] = {}
    for path in ds.shard_paths(root):
        # The shard's name carries its task and episode even when it holds no case.
        m = path.stem.split("-")
        key, episode = f"{'-'.join(m[1:-2])}/{int(m[-2])}", int(m[-1])
        entry = out.setdefault(key, {"episodes": set(), "success": 0, "failure": 0})
        entry["episodes"].add(episode)
    if out:
        table = ds.read_cases(root, columns=["task", "label"])
        for key, label in zip(table.column("task").to_pylist(), table.column("label").to_pylist()):
            out[key]["success" if label else "failure"] += 1
    return out


def _keep(rows: list[dict], have: dict, opts: CollectOptions) -> list[dict]:
    kept = []
    for row in rows:
        cls = "success" if row["label"] else "failure"
        if opts.balance:
            if have[cls] >= opts.per_task // 2 + (opts.per_task % 2 if cls == "failure" else 0):
                continue
        elif have["success"] + have["failure"] >= opts.per_task:
            break
        have[cls] += 1
        kept.append(row)
    return kept


def _done(have: dict, opts: CollectOptions) -> bool:
    if opts.balance:
        return (have["success"] >= opts.per_task // 2
                and have["failure"] >= opts.per_task // 2 + opts.per_task % 2)
    return have["success"] + have["failure"] >= opts.per_task


def collect(opts: CollectOptions, out: Path, *, progress: Callable | None = None) -> dict:
    """Collect (or continue collecting) cases into ``out``; returns a summary dict.

    ``progress(text, kept_now, total_kept)`` is called as episodes finish and while fresh init
    states are drawn."""
    from seal.sim.pool import EnvPool
    from seal.sim.suites import get_task
    from seal.steer.build import build_episode
    from seal.steer.method import MethodSpec

    opts.check()
    out = Path(out)
    spec = MethodSpec(method="seal", k=opts.k, rounds=opts.rounds, verifier="oracle", policy=opts.policy,
                      knobs=opts.knobs, **opts.method_settings)
    info_path = out / "info.json"
    if info_path.is_file():
        old = ds.read_info(out).get("collection", {}).get("settings", {})
        changed = {k: (old.get(k), v) for k, v in opts.settings().items() if old.get(k) != v}
        if changed:
            raise InvalidInput(f"{out} was collected with other settings ({', '.join(f'{k}: {a!r} now {b!r}' for k, (a, b) in changed.items())}); "
                               "use another --out, or the same settings to continue")
    have_all = existing(out)
    tasks_info = ds.read_info(out)["collection"].get("task_init_states", {}) if info_path.is_file() else {}
    unknown = episodes_run = 0
    max_episodes = opts.max_episodes or 4 * opts.per_task

    def save_info():
        counts = have_all
        ds.write_info(out, {"collection": {
            "settings": opts.settings(), "tasks": sorted({*counts, *tasks_info}), "per_task": opts.per_task,
            # the pixels' render model (the policy's own for a learned VLA): a verifier trained on one sees the
            # other's images out of distribution. Not a setting: it follows from the policy.
            "render_mode": spec.render,
            # which weights made the states (a learned policy's digest, as in method labels): a verifier
            # trained on these cases names the policy version it saw (its manifest's `case_policies`)
            "policy_ckpt_digest": spec.canonical().get("policy_ckpt"),
            "init_sources": {"official": "LIBERO's evaluation init states (episode e uses index e mod their count)",
                             "fresh-train": f"fresh states drawn with seeds task_seed + {FRESH_SEED_OFFSET['fresh-train']} + j",
                             "fresh-heldout": f"fresh states drawn with seeds task_seed + {FRESH_SEED_OFFSET['fresh-heldout']} + j"},
            "task_init_states": tasks_info,
            "counts": {k: {"success": v["success"], "failure": v["failure"], "episodes": len(v["episodes"])}
                       for k, v in sorted(counts.items())}}})

    # cases kept so far by the tasks asked for (a run continuing some tasks of a collection counts
    # against their target, not the other tasks' cases)
    keys = {get_task(opts.suite, t).key for t in opts.tasks}
    total = sum(v["success"] + v["failure"] for k, v in have_all.items() if k in keys)
    skipped: dict[str, str] = {}  # task -> why it was given up (the other tasks go on)
    for task_id in opts.tasks:
        task = get_task(opts.suite, task_id)
        have = have_all.setdefault(task.key, {"episodes": set(), "success": 0, "failure": 0})
        if _done(have, opts) or len(have["episodes"]) >= max_episodes:
            continue
        if opts.init_source == "official":
            run_task, seeds = task, None
            n_inits = len(task.init_states())
        else:
            def drew(i, n, key=task.key):
                if progress is not None:
                    progress(f"{key}: drawing fresh init states {i}/{n}", 0, total)
            try:
                run_task, seeds = fresh_init_states(task, opts.init_source, opts.inits_per_task, out, drew)
            except InvalidInput as exc:  # this scene's sampler gives no usable start: say so, go on
                skipped[task.key] = str(exc)
                continue
            n_inits = len(seeds)
        tasks_info[task.key] = {"init_source": opts.init_source, "init_states": n_inits,
                                "init_file": str(Path(run_task.init_states_path).relative_to(out))
                                if opts.init_source != "official" else str(task.init_states_path)}
        episode = max(have["episodes"], default=-1) + 1
        with EnvPool(run_task, k=spec.effective_k, workers=opts.workers, render_mode=spec.render,
                     physics=spec.physics()) as pool:
            barren = 0  # episodes in a row that kept nothing
            while not _done(have, opts) and len(have["episodes"]) < max_episodes:
                if barren >= opts.patience:
                    missing = "successes" if have["success"] < opts.per_task // 2 else "failures"
                    skipped[task.key] = (f"{barren} episodes in a row kept no case (still missing {missing}; "
                                         "a sub-plan whose success ends the task is never judged)")
                    break
                init_index = episode % n_inits
                seed = _episode_seed(task.key, opts.init_source, episode)
                base = {"suite": task.suite, "task_id": task.task_id, "task": task.key,
                        "init_source": opts.init_source, "init_index": init_index,
                        "init_seed": -1 if seeds is None else int(seeds[init_index]), "episode": episode,
                        "seed": seed, "policy": opts.policy, "knobs": opts.knobs, "instruction": task.instruction}
                recorder = CaseRecorder(base)
                with build_episode(spec, run_task, seed=seed, pool=pool, max_steps=opts.max_steps,
                                   verifier=ImagesOracle(), subscribers=(recorder,)) as ep:
                    if not opts.early_exit:
                        ep.steerer.selection = WholeRounds()
                    ep.run(init_index)
                kept = _keep(recorder.rows, have, opts)
                barren = 0 if kept else barren + 1
                ds.write_shard(out, ds.shard_name(task.suite, task.task_id, episode), kept)
                have["episodes"].add(episode)
                unknown += recorder.unknown
                episodes_run += 1
                total += len(kept)
                save_info()
                if progress is not None:
                    progress(f"{task.key} episode {episode}: {have['success']} successes, {have['failure']} failures",
                             len(kept), total)
                episode += 1
    save_info()
    counts = ds.read_info(out)["collection"]["counts"]
    return {"out": str(out.resolve()), "episodes_run": episodes_run, "ungroundable_skipped": unknown,
            "cases": sum(v["success"] + v["failure"] for v in counts.values()), "counts": counts,
            "init_source": opts.init_source, "tasks_given_up": skipped}
