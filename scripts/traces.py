#!/usr/bin/env python
"""Keep a results database's per-trial traces with the repository, in small append-only archives.

A `seal eval` database stores each trial's figures; the trace beside it (every sub-plan, candidate and
verdict, `trace.jsonl`) lives in the run directory in ../runs, which is lost with the machine. `seal
report` needs the traces for its failure causes and committed-pass audit. This packs the traces that no
earlier archive holds into one new .tar.xz (a SEAL trial's trace is ~110 kB, ~10 kB compressed; candidate
grids and videos are left out), and unpacks every archive where `seal report` looks for them.

    python scripts/traces.py pack   results/generalization_v3.db --runs ../runs/eval/generalization_v3_runs
    python scripts/traces.py unpack results/generalization_v3.db     # -> results/generalization_v3_runs/

Archives go to <db without .db>_traces/<UTC date>-<n>.tar.xz; members are named
suite/task/method-hash/trialNNN/trace.jsonl, the tail `seal report --runs` resolves. Packing twice adds
nothing; an archive is never rewritten, so a committed one stays as it was.
"""

from __future__ import annotations

import argparse
import io
import json
import sqlite3
import sys
import tarfile
import time
from pathlib import Path

from seal.report.data import TRIAL_FILE_PARTS, default_runs_dir


def archive_dir(db: Path) -> Path:
    return db.with_name(db.stem + "_traces")


def member_name(stored: str) -> str | None:
    parts = Path(stored).parts
    return "/".join(parts[-TRIAL_FILE_PARTS:]) if len(parts) >= TRIAL_FILE_PARTS else None


def archived(where: Path) -> set[str]:
    names: set[str] = set()
    for path in sorted(where.glob("*.tar.xz")):
        with tarfile.open(path, "r:xz") as tar:
            names.update(tar.getnames())
    return names


def stored_traces(db: Path) -> list[str]:
    if not db.is_file():
        raise SystemExit(f"traces: no results database at {db}")
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return [r[0] for r in con.execute("SELECT trace_path FROM trials WHERE trace_path != '' ORDER BY finished_at")]
    finally:
        con.close()


def pack(db: Path, runs: Path, out_dir: Path) -> dict:
    have = archived(out_dir)
    todo: list[tuple[str, Path]] = []
    missing = 0
    for stored in stored_traces(db):
        name = member_name(stored)
        if name is None or name in have:
            continue
        # the file as stored, or the same tail under --runs (the run directory moved, or the DB is a snapshot)
        for candidate in (Path(stored), runs.joinpath(*name.split("/"))):
            if candidate.is_file():
                todo.append((name, candidate))
                break
        else:
            missing += 1
    if not todo:
        return {"archive": None, "added": 0, "already_archived": len(have), "not_on_disk": missing}
    out_dir.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y-%m-%d", time.gmtime())
    n = 1
    while (out := out_dir / f"{stamp}-{n}.tar.xz").exists():
        n += 1
    tmp = out.with_suffix(".partial")
    with tarfile.open(tmp, "w:xz", preset=9) as tar:
        for name, path in todo:
            data = path.read_bytes()  # a trial still running is not in the DB, so its trace is complete
            info = tarfile.TarInfo(name)
            info.size, info.mtime, info.mode = len(data), int(path.stat().st_mtime), 0o644
            tar.addfile(info, io.BytesIO(data))
    tmp.rename(out)  # a crash mid-write leaves a .partial, never a short archive under the real name
    return {"archive": str(out), "added": len(todo), "bytes": out.stat().st_size,
            "already_archived": len(have), "not_on_disk": missing}


def unpack(out_dir: Path, runs: Path) -> dict:
    archives = sorted(out_dir.glob("*.tar.xz"))
    if not archives:
        raise SystemExit(f"traces: no archives in {out_dir}")
    written = 0
    for path in archives:
        with tarfile.open(path, "r:xz") as tar:
            members = [m for m in tar.getmembers() if m.isfile() and m.name.endswith("/trace.jsonl")]
            tar.extractall(runs, members=members, filter="data")  # "data": no absolute paths, links or ..
            written += len(members)
    return {"archives": len(archives), "traces": written, "runs": str(runs)}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", choices=["pack", "unpack"])
    p.add_argument("db", type=Path, help="a `seal eval` results database")
    p.add_argument("--runs", type=Path, default=None,
                   help="the run's trial directory (default: <db without .db>_runs, where `seal report` looks)")
    p.add_argument("--archives", type=Path, default=None, help="archive directory (default: <db without .db>_traces)")
    args = p.parse_args()
    runs = args.runs or default_runs_dir(args.db)
    where = args.archives or archive_dir(args.db)
    result = pack(args.db, runs, where) if args.action == "pack" else unpack(where, runs)

    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
