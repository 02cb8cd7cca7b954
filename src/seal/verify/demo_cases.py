"""Verification cases from recorded demonstrations: replay each one, stop along every sub-plan,
and let the oracle label what the three views show.

Why: SEAL rounds (`seal.collect`) are the faithful source of cases but a slow one (a round of K
rollouts yields at most K cases, and most candidates of a good policy succeed). A demonstration
already walks through every sub-plan, and the states *inside* a sub-plan are the hard negatives
a verifier must refuse: the can lifted but still above the basket, the drawer half shut. Replaying
a demonstration costs one rollout and gives several cases per sub-plan.

How a demonstration becomes cases (``seal verify from-demos``):

- The dataset must come from `seal demos record` with sampled starts: each episode's meta holds
  its start seed, the sub-plans and the frame at which each sub-plan's goal first held
  (``critical_frames``). The episode is replayed in the render mode it was recorded in, from the
  same start. Datasets store actions as float32, and a contact-rich replay of float32-rounded
  actions drifts (about 1 in 10 LIBERO-10 demonstrations then fails: a bowl that tips over the
  drawer's lip); so by default (``rerun_expert``) the scripted expert is first run again from the
  same start without rendering, which reproduces the recording bit for bit (its float32 actions
  must equal the stored ones, else the stored actions are used), and its float64 actions are
  replayed. A replay that still does not end in success is skipped and counted.
- Sub-plan i runs from the frame where sub-plan i-1 was achieved (0 for the first) to its own
  critical frame e. Its "before" view is the front camera at the start frame; the candidate end
  states are the frames at ``fractions`` of the way to e (1.0 is e itself) and ``after`` frames
  past e (the state a candidate that kept going would reach).
- Each end state is labelled by the oracle exactly as in `seal verify collect`: the sub-plan is
  grounded to goal atoms and checked in that state. The label is the simulator's, not the
  fraction's: a can dropped in the basket early is a success wherever it is caught.

- Near misses (``branches`` > 0): a demonstration's end states short of a sub-plan's end are
  failures of one kind only, "not there yet". The failures a verifier most often calls successes
  are the other kind: the object released beside its target, the gripper closed next to the
  handle. A branch makes one: from ``branch_from`` of the way through the sub-plan, the recorded
  actions are replayed with a constant horizontal offset, in a seeded direction, sized so that the
  hand ends about ``branch_miss`` metres from where the demonstration put it, up to ``after``
  frames past the sub-plan's end; that state is judged, and the world is restored to where the
  branch left the recording. The oracle labels it like any other: a branch that still succeeds is a success.
- Idle-gripper branches (``grip_branch``): the other near miss a learned policy makes is a hand
  that goes everywhere it should while its gripper does nothing: it lifts an empty hand over the
  can, or holds the box above the basket and never lets go. This branch replays a sub-plan from
  its start, up to ``after`` frames past its end, with every gripper command replaced by the
  sub-plan's first one (case ids end ``:g``).
- Task-level cases (``task_cases``): when a policy writes that the task is done, SEAL asks whether
  the instruction holds (``done_check``). A verifier learns to answer that only from task-level
  cases, and SEAL rounds make few (a claim per episode at most). A demonstration gives one at
  every sub-plan's end, where a policy is likeliest to claim too early (the soup in the basket,
  the sauce not yet: a failure), and one at its last frame (a success); the oracle checks the
  task's goal atoms (case ids ``...:task:f<frame>``, kind ``task``, the episode's first view as
  "before", ``subplan_index`` 0, ``steps`` the frame).

Rows have the columns of `seal.verify.dataset` with ``init_source="demo"``, ``init_index`` the
dataset's episode index, ``init_seed`` its start seed, ``policy="scripted"``, ``knobs="demo"``,
``round=0``, ``candidate`` the end frame's position in the list, ``steps`` the frames since the
sub-plan began and ``ended_by="demo"``. `seal train verifier` uses such cases for training only:
they are never part of a held-out split (their starts and actions are not SEAL's).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from seal.errors import InvalidInput, SimulationError
from seal.sim.control import METRES_PER_ACTION
from seal.verify import dataset as ds
from seal.verify.base import VerifyRequest
from seal.verify.oracle import OracleVerifier

SOURCE = ds.DEMO_SOURCE


@dataclass(frozen=True)
class DemoCaseOptions:
    fractions: tuple[float, ...] = (0.3, 0.6, 0.8, 0.9, 1.0)  # of the way from a sub-plan's start to its end
    after: int = 10  # one more end state this many frames past the sub-plan's end (0: none)
    episodes_per_task: int | None = None  # the first N episodes of each task (default: all)
    # skip each task's first N episodes: a held-out set from demonstrations an earlier collection
    # (made with episodes_per_task=N) already turned into training cases
    skip_per_task: int = 0
    branches: int = 0  # near-miss branches per sub-plan (module docstring)
    branch_from: float = 0.5  # where a branch leaves the recording, as a fraction of the sub-plan
    branch_miss: float = 0.05  # metres between where a branch's hand ends and where the demonstration's did
    grip_branch: bool = False  # one more branch per sub-plan: the gripper held as it began (module docstring)
    only_branches: bool = False  # write the branch cases alone (near misses for a collection made without them)
    # task-level cases: "does the instruction hold?" at every sub-plan's end and the episode's last frame,
    # as SEAL asks when a policy says the task is done (module docstring)
    task_cases: bool = False
    rerun_expert: bool = True  # replay the expert's exact float64 actions, recovered by running it again

    def settings(self) -> dict:
        out = {"source": SOURCE, "fractions": list(self.fractions), "after": self.after}
        if self.branches:  # collections made before branches existed keep their settings
            out |= {"branches": self.branches, "branch_from": self.branch_from, "branch_miss": self.branch_miss}
        if self.grip_branch:
            out["grip_branch"] = True
        if self.only_branches:
            out["only_branches"] = True
        if self.task_cases:
            out["task_cases"] = True
        if self.rerun_expert:  # collections made before it replayed the stored float32 actions
            out["rerun_expert"] = True
        return out

    def check(self) -> None:
        if not self.fractions or any(not 0.0 < f <= 1.0 for f in self.fractions):
            raise InvalidInput(f"--fractions must be numbers in (0, 1], got {list(self.fractions)}")
        if self.after < 0:
            raise InvalidInput(f"--after must be >= 0 frames, got {self.after}")
        if self.skip_per_task < 0:
            raise InvalidInput(f"--skip-episodes-per-task must be >= 0, got {self.skip_per_task}")
        if self.branches < 0 or not 0.0 <= self.branch_from < 1.0 or not 0.0 < self.branch_miss <= 0.3:
            raise InvalidInput(f"--branches must be >= 0, --branch-from in [0, 1) and --branch-miss in (0, 0.3] metres; "
                               f"got {self.branches}, {self.branch_from}, {self.branch_miss}")
        if self.only_branches and not (self.branches or self.grip_branch or self.task_cases):
            raise InvalidInput("--only-branches needs --branches N, --grip-branch or --task-cases (it writes their "
                               "cases alone)")


def branch_offsets(episode: int, segment: int, frames: int, opts: DemoCaseOptions) -> list[np.ndarray]:
    """The (dx, dy) action offsets of one sub-plan's branches, each added to every one of its
    ``frames`` actions: evenly spread directions, turned by a seeded angle so that episodes do not
    all miss the same way, each as large as ends the hand ``branch_miss`` away."""
    turn = np.random.default_rng([episode, segment]).uniform(0, 2 * np.pi)
    angles = turn + 2 * np.pi * np.arange(opts.branches) / max(opts.branches, 1)
    size = min(1.0, opts.branch_miss / (METRES_PER_ACTION * max(frames, 1)))
    return [size * np.array([np.cos(a), np.sin(a)]) for a in angles]


def end_frames(start: int, end: int, length: int, opts: DemoCaseOptions) -> list[int]:
    """The frames judged as candidate end states of a sub-plan that ran from ``start`` to ``end``
    (distinct, in order; frame ``length`` is the state after the last recorded action)."""
    frames = [start + max(1, round(f * (end - start))) for f in opts.fractions]
    if opts.after:
        frames.append(end + opts.after)
    out: list[int] = []
    for f in frames:
        f = min(f, length)
        if f > start and f not in out:
            out.append(f)
    return out


def _segments(meta: dict) -> list[tuple[str, int, int]]:
    """(sub-plan, start frame, end frame) of one recorded episode."""
    subplans, critical = meta.get("subplans"), meta.get("critical_frames")
    if not subplans or critical is None or len(subplans) != len(critical):
        raise InvalidInput("episode meta lacks matching 'subplans' and 'critical_frames' "
                           "(record the dataset with `seal demos record`)")
    out, start = [], 0
    for text, end in zip(subplans, critical):
        if end is None or end < 0:  # this sub-goal never held: the rest cannot be placed in time
            break
        if end > start:
            out.append((text, start, int(end)))
        start = max(start, int(end))
    return out


def replay_cases(world, meta: dict, actions: np.ndarray, base: dict, opts: DemoCaseOptions) -> tuple[list[dict], bool]:
    """Replay one episode in ``world`` and return (case rows, whether the replay succeeded)."""
    oracle = OracleVerifier()
    plans = tuple(meta["subplans"])
    segments = _segments(meta)
    length = len(actions)
    world.reset_sampled(int(meta["meta"]["start_seed"]), max_draws=1)
    objects = None
    wanted: dict[int, list[tuple[int, str, int, int]]] = {}  # frame -> [(segment index, text, start, slot)]
    starts: set[int] = set()
    for i, (text, start, end) in enumerate(segments):
        starts.add(start)
        for slot, f in enumerate([] if opts.only_branches else end_frames(start, end, length, opts)):
            wanted.setdefault(f, []).append((i, text, start, slot))
    branch_at: dict[int, list[tuple[int, str, int, int]]] = {}  # frame -> [(segment index, text, start, stop)]
    if opts.branches:
        for i, (text, start, end) in enumerate(segments):
            at = start + int(opts.branch_from * (end - start))
            branch_at.setdefault(at, []).append((i, text, start, min(end + opts.after, length)))
    grip_at: dict[int, list[tuple[int, str, int]]] = {}  # sub-plan start -> [(segment index, text, stop)]
    if opts.grip_branch:
        for i, (text, start, end) in enumerate(segments):
            grip_at.setdefault(start, []).append((i, text, min(end + opts.after, length)))
    # task-level questions where a policy is likeliest to claim the task done: as each sub-plan ends
    task_at = ({end for _, _, end in segments} | {length}) if opts.task_cases else set()
    goal = tuple(str(a) for a in world.task.goal_atoms())
    first_views: dict[int, np.ndarray] = {}
    rows: list[dict] = []

    def judge(obs, i: int, text: str, start: int, case_id: str, slot: int, steps: int, goal_atoms=()) -> None:
        """Label one end state; with ``goal_atoms``, a task-level case (``i`` -1: no sub-plan)."""
        nonlocal objects
        if objects is None:
            scene = world.scene_state()
            objects = sorted(set(scene.bodies) | set(scene.sites))
        req = VerifyRequest(subplan=text, instruction=base["instruction"], plans=plans, index=None if i < 0 else i,
                            first_agent=first_views[start], final_agent=obs.agent, final_wrist=obs.wrist,
                            task=base["task"], goal_atoms=goal_atoms)
        req.scene = world.scene_state(oracle.atoms_needed(req, objects))
        verdict = oracle.judge(req)
        if verdict.success is not None:
            rows.append(ds.case_row(base, req, verdict, case_id=case_id, subplan_number=i + 1, round=0,
                                    candidate=slot, steps=steps, ended_by=SOURCE))

    prefix = f"{base['task']}:{SOURCE}:{base['init_index']}"
    for t in range(length + 1):
        # one render per frame
        obs = world.observe(images=True) if t in starts or t in wanted or t in task_at else None
        if t in starts:
            first_views[t] = obs.agent
        if t in task_at:
            judge(obs, -1, base["instruction"], 0, f"{prefix}:task:f{t}", 0, t, goal_atoms=goal)
        for i, text, start, slot in wanted.get(t, ()):
            judge(obs, i, text, start, f"{prefix}:s{i + 1}:f{t}", slot, t - start)
        for i, text, start, stop in branch_at.get(t, ()):
            if stop <= t:
                continue
            snap = world.snapshot()
            for j, (dx, dy) in enumerate(branch_offsets(base["init_index"], i, stop - t, opts)):
                shifted = actions[t:stop].copy()
                shifted[:, 0] += dx
                shifted[:, 1] += dy
                world.step_chunk(np.clip(shifted, -1.0, 1.0))
                judge(world.observe(images=True), i, text, start, f"{prefix}:s{i + 1}:b{j}", len(opts.fractions) + 1 + j,
                      stop - start)
                world.restore(snap)
        for i, text, stop in grip_at.get(t, ()):
            snap = world.snapshot()
            idle = actions[t:stop].copy()
            idle[:, -1] = actions[t, -1]  # the gripper keeps the sub-plan's first command throughout
            world.step_chunk(idle)
            judge(world.observe(images=True), i, text, t, f"{prefix}:s{i + 1}:g", len(opts.fractions) + 1 + opts.branches,
                  stop - t)
            world.restore(snap)
        if t < length:
            world.step(actions[t])
    return rows, bool(world.success())


def _task_of(meta: dict):
    from seal.sim.suites import get_task

    m = meta.get("meta") or {}
    if "suite" not in m or "task_id" not in m:
        raise InvalidInput("episode meta lacks suite/task_id (record the dataset with `seal demos record`)")
    return get_task(m["suite"], int(m["task_id"]))


def from_demos(dataset: Path, out: Path, opts: DemoCaseOptions, *, tasks: list[int] | None = None,
               progress: Callable | None = None, exact_actions: Callable | None = None) -> dict:
    """Write cases from the recorded episodes of ``dataset`` into ``out`` (resumable: an episode whose
    shard exists is not replayed again). ``tasks``: only these task ids. ``exact_actions(world, meta,
    stored)``: the recording's exact float64 actions or None (`seal.demos.exact_actions`, which runs the
    expert again; passed in because a verifier's module does not drive the expert), needed with
    ``opts.rerun_expert``."""
    from seal.datasets.lerobot import LeRobotReader
    from seal.sim.world import LiberoWorld

    opts.check()
    if opts.rerun_expert and exact_actions is None:
        raise InvalidInput("rerun_expert needs exact_actions (seal.demos.exact_actions); or replay the stored "
                           "actions (--replay-stored)")
    reader = LeRobotReader(Path(dataset))
    out = Path(out)
    settings = {**opts.settings(), "dataset": str(Path(dataset).resolve())}
    if (out / "info.json").is_file():
        old = ds.read_info(out).get("collection", {}).get("settings", {})
        per_run = {"episodes_per_task", "skip_per_task"}  # which episodes, not how: may differ between runs
        changed = sorted(k for k in {*settings, *old} - per_run if old.get(k) != settings.get(k))
        if changed:
            hint = (" (it was made replaying the stored actions: add --replay-stored to continue it)"
                    if changed == ["rerun_expert"] and opts.rerun_expert else "")
            raise InvalidInput(f"{out} holds cases made with other settings ({', '.join(changed)}){hint}; "
                               "use another --out, or the same settings to continue")
    done = {p.name for p in ds.shard_paths(out)}
    failed_before = ds.read_info(out)["collection"].get("replay_failed", []) if (out / "info.json").is_file() else []
    plan = []
    per_task: dict[str, int] = {}
    for e in range(reader.num_episodes):
        meta = reader.episode_meta(e)
        m = meta.get("meta") or {}
        if m.get("start") != "sampled" or "start_seed" not in m:
            raise InvalidInput(f"episode {e} of {dataset} did not start from a sampled state "
                               f"(start {m.get('start')!r}); cases come only from sampled starts, so "
                               "no evaluation init state enters training")
        if tasks is not None and int(m["task_id"]) not in tasks:
            continue
        key = f"{m['suite']}/{m['task_id']}"
        per_task[key] = per_task.get(key, 0) + 1
        if per_task[key] <= opts.skip_per_task:
            continue
        if opts.episodes_per_task is not None and per_task[key] > opts.skip_per_task + opts.episodes_per_task:
            continue
        plan.append((e, meta))
    summary = {"out": str(out.resolve()), "episodes": len(plan), "replayed": 0, "already_done": 0,
               "replay_failed": [], "rerun": 0, "cases": 0, "success": 0, "failure": 0}
    world, world_key = None, None
    try:
        for n, (e, meta) in enumerate(plan):
            task = _task_of(meta)
            shard = ds.shard_name(task.suite, task.task_id, e)
            if shard in done:
                summary["already_done"] += 1
                continue
            mode = (meta.get("meta") or {}).get("render_mode", "stock")
            if (task.key, mode) != world_key:
                if world is not None:
                    world.close()
                world, world_key = LiberoWorld(task, render_mode=mode), (task.key, mode)
            actions = np.asarray(reader.frames(e).column("action").to_pylist(), dtype=np.float64)
            if opts.rerun_expert:
                exact = exact_actions(world, meta, actions)
                if exact is not None:
                    actions = exact
                    summary["rerun"] += 1
            base = {"suite": task.suite, "task_id": task.task_id, "task": task.key, "init_source": SOURCE,
                    "init_index": e, "init_seed": int(meta["meta"]["start_seed"]), "episode": e, "seed": -1,
                    "policy": "scripted", "knobs": SOURCE, "instruction": task.instruction}
            try:
                rows, ok = replay_cases(world, meta, actions, base, opts)
            except SimulationError:  # the recorded start cannot be drawn again (another LIBERO version?)
                rows, ok = [], False
            if not ok:  # the replay drifted from the recording: its labels would still be true, but
                rows = []  # its states are not the demonstration's; keep the data set honest
                summary["replay_failed"].append(e)
            ds.write_shard(out, shard, rows)
            summary["replayed"] += 1
            summary["cases"] += len(rows)
            summary["success"] += sum(r["label"] for r in rows)
            summary["failure"] += sum(not r["label"] for r in rows)
            ds.write_info(out, {"collection": {"settings": settings,
                                               "replay_failed": sorted({*failed_before, *summary["replay_failed"]})}})
            if progress is not None:
                progress(n + 1, len(plan), f"episode {e} ({task.key}): {len(rows)} cases")
    finally:
        if world is not None:
            world.close()
    if not (out / "info.json").is_file():
        ds.write_info(out, {"collection": {"settings": settings, "replay_failed": []}})
    return summary
