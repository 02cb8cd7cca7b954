"""Verification cases on disk: what a verifier was shown, and what the simulator says is true.

One case is one candidate outcome of a SEAL round: the three images a VLM verifier receives
(224x224 PNG, exactly the bytes `seal.vlm.encode_image` would send), the texts around them and
the oracle's label. The layout is plain parquet plus one JSON file, so anyone can load it
without SEAL (docs/verifier.md):

    DIR/info.json                                   format, schema (column -> type, meaning),
                                                    how the cases were collected, counts
    DIR/data/shard-<suite>-<task>-<episode>.parquet  one row per case, one file per episode
    DIR/init_states/<suite>-<task>-<source>.npz      the fresh init states used (states, seeds)

A shard is written aside and renamed into place, so an interrupted run leaves whole shards
only; files whose names start with ``.`` (the half-written ones) are ignored by this reader
and by ``pyarrow.dataset``.
"""

from __future__ import annotations

import io
import json
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seal.errors import InvalidInput
from seal.verify.base import VerifyRequest

FORMAT = "seal-verification-cases"
VERSION = 1
IMAGE_SIZE = 224
IMAGE_COLUMNS = ("first_agent", "final_agent", "final_wrist")
DEMO_SOURCE = "demo"  # init_source of cases replayed from demonstrations (`seal.verify.demo_cases`)
# turn: turn on / turn off; task: a task-level case (does the instruction hold? asked when the policy
# says the task is done), labelled on the task's goal atoms. Appended last so that readers which list
# kinds in this order keep the sub-plan kinds where they were.
KINDS = ("pick", "place", "open", "close", "turn", "other", "task")

# column -> (arrow type name, meaning); the order is the file's column order.
COLUMNS: dict[str, tuple[str, str]] = {
    "case_id": ("string", "unique id: task, init source and index, episode, sub-plan, round, candidate"),
    "suite": ("string", "task suite, e.g. libero_10"),
    "task_id": ("int32", "task id within the suite"),
    "task": ("string", "suite/task_id, e.g. libero_10/0"),
    "init_source": ("string", "official (LIBERO's evaluation starts) | fresh-train | fresh-heldout | "
                              "demo (replayed from a recorded demonstration's sampled start); DAgger rollouts' "
                              "cases are fresh-train (their starts: `seal.dagger.dagger_seed`, in init_seed)"),
    "init_index": ("int32", "index of the init state within its source"),
    "init_seed": ("int64", "placement-sampler seed that drew a fresh init state (-1: official)"),
    "episode": ("int32", "episode number of this task in the collection"),
    "seed": ("int64", "the episode's seed (policy sampling)"),
    "policy": ("string", "policy that proposed the candidates (scripted, vla, ...)"),
    "knobs": ("string", "scripted expert's failure setting (clean | misaligned)"),
    "instruction": ("string", "the task instruction"),
    "plans": ("list<string>", "every sub-plan of the policy's plan, in order"),
    "subplan": ("string", "the sub-plan being judged (kind task: the instruction)"),
    "subplan_index": ("int32", "position of subplan in plans (-1: not in it)"),
    "subplan_number": ("int32", "1-based count of sub-plans started so far in the episode"),
    "kind": ("string", "pick | place | open | close | turn (on/off) | other | task (the instruction, judged on "
                       "the task's goal atoms)"),
    "round": ("int32", "sampling round of the sub-plan (0-based)"),
    "candidate": ("int32", "candidate slot within the round"),
    "steps": ("int32", "control steps the candidate ran for this sub-plan"),
    "ended_by": ("string", "think | budget | step_limit | midway (a mid-rollout check) | demo; DAgger rollouts "
                           "(`seal demos dagger --verifier-cases`): think, vla_done (the policy declared the task "
                           "done), task_success (LIBERO's check first held), before_release (a place's last "
                           "closed-gripper state)"),
    "label": ("bool", "the oracle's verdict: the sub-plan's goal atoms all hold (positive = success)"),
    "atoms": ("list<string>", "goal atoms the oracle grounded the sub-plan to (kind task: the task's goal atoms)"),
    "atom_values": ("list<bool>", "their truth in the candidate's end state"),
    "objects": ("list<string>", "object and region names of the scene (what the oracle grounds with)"),
    "first_agent": ("binary", "PNG 224x224 RGB: front (agent) camera when the sub-plan started"),
    "final_agent": ("binary", "PNG 224x224 RGB: front camera at the candidate's end state"),
    "final_wrist": ("binary", "PNG 224x224 RGB: wrist camera at the candidate's end state"),
}


def arrow_schema():
    import pyarrow as pa

    types = {"string": pa.string(), "int32": pa.int32(), "int64": pa.int64(), "bool": pa.bool_(),
             "binary": pa.binary(), "list<string>": pa.list_(pa.string()), "list<bool>": pa.list_(pa.bool_())}
    return pa.schema([(name, types[kind]) for name, (kind, _) in COLUMNS.items()])


# ---- sub-plan kinds ------------------------------------------------------------------------------
_KIND_OF_PREDICATE = {"Grasped": "pick", "In": "place", "On": "place", "Open": "open", "Close": "close",
                      "TurnOn": "turn", "TurnOff": "turn"}
_VERBS = (("pick", r"^(pick|grab|grasp|take|lift|hold)\b"),
          ("place", r"^(place|put|set|move|transfer|drop|stack|bring|insert|slide|stand|lay)\b"),
          ("open", r"^open\b"), ("close", r"^(close|shut)\b"), ("turn", r"^(turn|switch)\b"))


def subplan_kind(subplan: str, atoms=()) -> str:
    """pick / place / open / close / turn / other: from the grounded goal atoms when there are any
    (``"Grasped(x)"`` -> pick), else from the sub-plan's first verb."""
    kinds = {_KIND_OF_PREDICATE.get(str(a).split("(", 1)[0]) for a in atoms} - {None}
    if len(kinds) == 1:
        return kinds.pop()
    text = subplan.strip().lower()
    for kind, pattern in _VERBS:
        if re.match(pattern, text):
            return kind
    return "other"


# ---- scoring -------------------------------------------------------------------------------------------
def binary_metrics(labels, predicted) -> dict:
    """accuracy, precision, recall, F1 (positive = success), the confusion matrix and the error rates."""
    y = np.asarray(labels, dtype=bool)
    p = np.asarray(predicted, dtype=bool)
    tp, fp = int((y & p).sum()), int((~y & p).sum())
    fn, tn = int((y & ~p).sum()), int((~y & ~p).sum())
    n = tp + fp + fn + tn

    def ratio(a, b):
        return round(a / b, 4) if b else None

    prec, rec = ratio(tp, tp + fp), ratio(tp, tp + fn)
    f1 = round(2 * prec * rec / (prec + rec), 4) if prec and rec else (0.0 if prec == 0 or rec == 0 else None)
    return {"n": n, "accuracy": ratio(tp + tn, n), "precision": prec, "recall": rec, "f1": f1,
            "confusion": {"tp": tp, "fp": fp, "fn": fn, "tn": tn},
            "fp_rate": ratio(fp, fp + tn), "fn_rate": ratio(fn, fn + tp)}


# ---- images --------------------------------------------------------------------------------------
def encode_png(image: np.ndarray) -> bytes:
    from seal.vlm import encode_image

    return encode_image(image, "png", "image")


def decode_png(data: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


# ---- writing -------------------------------------------------------------------------------------
def shard_name(suite: str, task_id: int, episode: int) -> str:
    return f"shard-{suite}-{task_id:03d}-{episode:05d}.parquet"


def write_shard(root: Path, name: str, rows: list[dict]) -> Path:
    """Write one shard atomically (aside, then renamed); an empty list writes an empty shard,
    which still records that the episode ran."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    data = Path(root) / "data"
    data.mkdir(parents=True, exist_ok=True)
    missing = [c for c in COLUMNS if rows and c not in rows[0]]
    if missing:
        raise InvalidInput(f"case rows lack column(s) {missing}")
    table = pa.Table.from_pylist(rows, schema=arrow_schema()) if rows else arrow_schema().empty_table()
    fd, tmp = tempfile.mkstemp(dir=data, prefix=".", suffix=".parquet.tmp")
    os.close(fd)
    try:
        pq.write_table(table, tmp)
        os.chmod(tmp, 0o644)  # mkstemp's owner-only mode would hide the data from other users
        os.replace(tmp, data / name)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return data / name


def write_info(root: Path, info: dict) -> None:
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    doc = {"format": FORMAT, "version": VERSION, "image_size": IMAGE_SIZE, "image_encoding": "png",
           "kinds": list(KINDS),
           "columns": {name: {"type": kind, "meaning": meaning} for name, (kind, meaning) in COLUMNS.items()},
           **info}
    fd, tmp = tempfile.mkstemp(dir=root, prefix=".", suffix=".json.tmp")
    with os.fdopen(fd, "w") as f:
        json.dump(doc, f, indent=1)
    os.chmod(tmp, 0o644)
    os.replace(tmp, root / "info.json")


def case_row(base: dict, request: VerifyRequest, verdict, *, case_id: str, subplan_number: int, round: int,
             candidate: int, steps: int, ended_by: str) -> dict:
    """One case in this layout: what ``request`` showed a verifier, labelled by the oracle's ``verdict``
    (its grounded atoms in ``verdict.extra["atoms"]``, their truth in ``request.scene``). ``base``: the
    episode's columns (suite, task, init, seed, policy, ...)."""
    atoms = list(verdict.extra.get("atoms", []))
    scene = request.scene
    images = (request.first_agent, request.final_agent, request.final_wrist)
    return {**base, "case_id": case_id, "plans": list(request.plans), "subplan": request.subplan,
            "subplan_index": -1 if request.index is None else int(request.index), "subplan_number": subplan_number,
            # a task-level request is judged on the task's goal, whatever kinds of atom that goal holds
            "kind": "task" if request.task_level else subplan_kind(request.subplan, atoms),
            "round": int(round), "candidate": int(candidate),
            "steps": int(steps), "ended_by": ended_by, "label": bool(verdict.success), "atoms": atoms,
            "atom_values": [bool(scene.facts[a]) for a in atoms],
            "objects": sorted(set(scene.bodies) | set(scene.sites)),
            **{name: encode_png(img) for name, img in zip(IMAGE_COLUMNS, images)}}


# ---- reading -------------------------------------------------------------------------------------
def read_info(root: Path) -> dict:
    path = Path(root) / "info.json"
    if not path.is_file():
        raise InvalidInput(f"{root} holds no verification cases (no info.json); collect some with "
                           "`seal verify collect`")
    info = json.loads(path.read_text())
    if info.get("format") != FORMAT:
        raise InvalidInput(f"{path} is not a {FORMAT} info file (format {info.get('format')!r})")
    if info.get("version", 0) > VERSION:
        raise InvalidInput(f"{path} has format version {info['version']}; this SEAL reads up to {VERSION}")
    return info


def collection_digest(info: dict) -> str | None:
    """The digest of the learned policy whose rounds made a collection (None: the scripted expert, a
    demonstration replay, or a collection written before digests were recorded)."""
    c = info.get("collection", {})
    return c.get("policy_ckpt_digest") or c.get("vla_ckpt_digest")


def shard_paths(root: Path) -> list[Path]:
    return sorted(p for p in (Path(root) / "data").glob("*.parquet") if not p.name.startswith("."))


def read_cases(root: Path, columns: list[str] | None = None):
    """Every case of a collection as one pyarrow Table (``columns``: only these)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    read_info(root)
    tables = [pq.read_table(p, columns=columns) for p in shard_paths(root)]
    schema = arrow_schema()
    if columns is not None:
        schema = pa.schema([schema.field(c) for c in columns])
    return pa.concat_tables(tables) if tables else schema.empty_table()


def init_key_of(task: str, source: str, index: int) -> str:
    """One init state of one task: the unit the held-out-inits split draws and the bootstrap of
    `seal bench verifier` resamples (a start's cases share its scene)."""
    return f"{task}:{source}:{index}"


@dataclass
class Case:
    """One case, images decoded (224x224x3 uint8)."""

    row: dict
    images: tuple[np.ndarray, np.ndarray, np.ndarray]

    @property
    def label(self) -> bool:
        return bool(self.row["label"])

    @property
    def kind(self) -> str:
        return self.row["kind"]


def iter_cases(root: Path, *, limit: int | None = None, seed: int = 0):
    """Cases, decoded; with ``limit``, that many chosen by a fixed shuffle (a mix of tasks and
    kinds). Shards are read one at a time, so memory holds one shard's images, not all."""
    import pyarrow.parquet as pq

    read_info(root)
    paths = shard_paths(root)
    sizes = [pq.ParquetFile(p).metadata.num_rows for p in paths]
    chosen = np.random.default_rng(seed).permutation(sum(sizes))
    if limit is not None:
        chosen = chosen[:limit]
    chosen = np.sort(chosen)
    start = 0
    for path, size in zip(paths, sizes):
        rows = chosen[(chosen >= start) & (chosen < start + size)] - start
        start += size
        if len(rows) == 0:
            continue
        table = pq.read_table(path).take(rows)
        for row in table.to_pylist():
            yield Case(row, tuple(decode_png(row.pop(c)) for c in IMAGE_COLUMNS))


def to_request(case: Case) -> VerifyRequest:
    """The `VerifyRequest` a verifier gets for this case. The privileged end state holds only what
    the oracle needs: the scene's names and the recorded truth of the grounded atoms."""
    from seal.sim.scene import SceneState

    row = case.row
    zeros = np.zeros(3)
    scene = SceneState(eef_pos=zeros, eef_xmat=np.eye(3), finger_axis=zeros, gripper_width=0.0,
                       bodies=dict.fromkeys(row["objects"]),
                       facts=dict(zip(row["atoms"], (bool(v) for v in row["atom_values"]))))
    index = row["subplan_index"]
    # a task-level case asks again the question it was labelled on: the task's goal atoms, not a grounding
    # of the instruction's words (which the oracle could not ground)
    goal_atoms = tuple(row["atoms"]) if row["kind"] == "task" else ()
    return VerifyRequest(subplan=row["subplan"], instruction=row["instruction"], plans=tuple(row["plans"]),
                         index=None if index < 0 else index, first_agent=case.images[0],
                         final_agent=case.images[1], final_wrist=case.images[2], scene=scene,
                         task=row["task"], candidate=row["candidate"], goal_atoms=goal_atoms)
