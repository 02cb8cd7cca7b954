"""`seal suites ...`: list suites, draw contact sheets, generate derived data, check tasks.

A contact sheet shows every task's first frame (agent view, after the settle steps, as the
policy sees it) labelled with the task id, its instruction and what the variant changes, so a
person can check the variants by eye.

It sits above `sim` (not in it) because a check plans each task with the scripted expert:
`sim` must not know any policy.
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np

from seal.errors import InvalidInput
from seal.sim.suites import SUITES, TaskSpec, get_task, list_tasks, parse_task_ids, task_count
from seal.steer.grid import label_font

TILE = 224  # the policy image size
CAPTION_H = 84
COLUMNS = 5


# ---- list ----------------------------------------------------------------------------------
def describe(suite: str) -> list[dict]:
    return [{"task": s.task_id, "key": s.key, "instruction": s.instruction, "base": s.base_key, "change": s.change,
             "max_steps": s.max_steps} for s in list_tasks(suite)]


# ---- contact sheet -------------------------------------------------------------------------
def first_frame(spec: TaskSpec, init_index: int = 0) -> np.ndarray:
    """The agent-view image the policy sees at the start of trial ``init_index`` (224x224x3)."""
    from seal.sim.world import LiberoWorld

    world = LiberoWorld(spec)
    try:
        world.reset(init_index)
        return world.observe().agent
    finally:
        world.close()


def contact_sheet(frames: list[tuple[TaskSpec, np.ndarray]], title: str = ""):
    """A PIL image: one tile per task, its caption (key, instruction, change) below it."""
    from PIL import Image, ImageDraw

    rows = (len(frames) + COLUMNS - 1) // COLUMNS
    cols = min(COLUMNS, len(frames))
    head = 28 if title else 0
    sheet = Image.new("RGB", (cols * TILE, head + rows * (TILE + CAPTION_H)), "white")
    draw = ImageDraw.Draw(sheet)
    if title:
        draw.text((6, 6), title, fill="black", font=label_font(16))
    small, tiny = label_font(12), label_font(10)
    for i, (spec, img) in enumerate(frames):
        x, y = (i % COLUMNS) * TILE, head + (i // COLUMNS) * (TILE + CAPTION_H)
        sheet.paste(Image.fromarray(np.asarray(img, dtype=np.uint8)), (x, y))
        lines = textwrap.wrap(f"{spec.task_id}: {spec.instruction}", 36)[:3]
        ty = y + TILE + 3
        for line in lines:
            draw.text((x + 4, ty), line, fill="black", font=small)
            ty += 14
        for line in textwrap.wrap(spec.change, 44)[: max(0, 5 - len(lines))]:
            draw.text((x + 4, ty), line, fill=(90, 90, 90), font=tiny)
            ty += 12
    return sheet


def show(suite: str, out: Path, tasks: list[int], init_index: int = 0, progress=None) -> Path:
    frames = []
    for t in tasks:
        spec = get_task(suite, t)
        if progress is not None:
            progress(spec)
        frames.append((spec, first_frame(spec, init_index)))
    out.parent.mkdir(parents=True, exist_ok=True)
    contact_sheet(frames, title=f"{suite}: first frames (agent view, init state {init_index})").save(out)
    return out


# ---- check ---------------------------------------------------------------------------------
def check_task(spec: TaskSpec, inits: int = 5) -> dict:
    """Build the task's world and check what an evaluation relies on; returns a report row.

    ``ok`` is False when: the init states do not fit the model's state vector or are fewer
    than 50; generated states do not belong to the current BDDL file; the first frame is blank;
    the expert cannot plan the task; or (visual_viewpoint) an object the LIBERO-10 camera sees
    in a checked init state is out of the moved camera's view.
    """
    from seal.policies.expert.plan import plan_task
    from seal.sim.generate import is_current, needs_generated_states
    from seal.sim.world import LiberoWorld

    row: dict = {"task": spec.key, "problems": []}
    world = LiberoWorld(spec)
    try:
        states = world.init_states
        dim = 1 + world.model.nq + world.model.nv
        row["init_states"] = list(states.shape)
        if states.ndim != 2 or states.shape[1] != dim:
            row["problems"].append(f"init states have shape {states.shape}, the model needs (n, {dim})")
        if len(states) < 50:
            row["problems"].append(f"only {len(states)} init states (evaluation uses 50)")
        if needs_generated_states(spec) and not is_current(spec):
            row["problems"].append("stored init states belong to another version of the BDDL file")
        picks = sorted({int(i) for i in np.linspace(0, len(states) - 1, max(1, inits))})
        out_of_view = set()
        for i in picks:
            world.reset(i, settle=False)
            out_of_view |= set(world.objects_out_of_view())
        world.reset(picks[0])
        img = world.observe().agent
        row["frame_std"] = round(float(img.std()), 1)
        if img.std() < 10:
            row["problems"].append("first frame is (nearly) blank")
    finally:
        world.close()
    row["out_of_view"] = sorted(out_of_view)
    if spec.suite == "visual_viewpoint":
        base_suite, base_id = spec.base_key.split("/")
        base = LiberoWorld(get_task(base_suite, int(base_id)))
        try:
            base_out = set()
            for i in picks:
                base.reset(i, settle=False)
                base_out |= set(base.objects_out_of_view())
        finally:
            base.close()
        lost = sorted(out_of_view - base_out)
        if lost:
            row["problems"].append(f"out of view after the camera move: {', '.join(lost)}")
    try:
        row["plan"] = [p.text for p in plan_task(spec)]
    except InvalidInput as exc:
        row["problems"].append(f"expert cannot plan: {exc}")
    row["ok"] = not row["problems"]
    return row


# ---- command -------------------------------------------------------------------------------
def main(args) -> int:
    from rich.console import Console

    console = Console(stderr=True)
    cmd = args.suites_command
    if cmd == "list":
        suites = [args.suite] if args.suite else list(SUITES)
        for s in suites:
            task_count(s)  # validates the name
        print(json.dumps({s: {"tasks": task_count(s), "rows": describe(s)} if s != "libero_90" else
                          {"tasks": task_count(s)} for s in suites}, indent=2))
        return 0
    suite = args.suite
    tasks = parse_task_ids(suite, args.tasks)
    if cmd == "show":
        with console.status("") as status:
            out = show(suite, Path(args.out), tasks, args.init,
                       progress=lambda spec: status.update(f"rendering {spec.key}"))
        print(json.dumps({"suite": suite, "tasks": tasks, "out": str(out)}))
        return 0
    if cmd == "generate":
        from seal.progress import Progress

        from seal.sim.generate import generate_suite

        with Progress(console=console) as bar:
            job = bar.add_task(f"{suite}", total=args.n)

            def progress(spec, i, total):
                bar.update(job, completed=i, total=total, description=f"{spec.key} init states")

            result = generate_suite(suite, tasks, n=args.n, force=args.force, progress=progress)
        print(json.dumps({"suite": suite, "tasks": result}, indent=2))
        return 0
    if cmd == "check":
        rows = []
        with console.status("") as status:
            for t in tasks:
                spec = get_task(suite, t)
                status.update(f"checking {spec.key}")
                rows.append(check_task(spec, args.inits))
        print(json.dumps({"suite": suite, "ok": all(r["ok"] for r in rows), "tasks": rows}, indent=2))
        return 0 if all(r["ok"] for r in rows) else 1
    raise InvalidInput(f"unknown suites command {cmd!r}; valid: list, show, generate, check")
