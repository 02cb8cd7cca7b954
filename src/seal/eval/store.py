"""The results store: one SQLite row per finished trial, written the moment it finishes.

Why SQLite: one file a person can copy, query with any tool and merge; atomic commits mean a
run killed mid-write loses at most the trial in flight, and the primary key makes resuming
exact (a finished trial is never run or stored twice).

The store refuses files it did not create (a foreign or corrupted database is never touched),
and refuses a newer schema than it knows.
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from seal.errors import InvalidInput

SCHEMA_VERSION = 6  # v2 added trials.policy_s, v3 trials.verifier_errors and verifier_unavailable,
# v4 trials.subplans_audited and subplans_aligned, v5 trials.ended_by, v6 trials.done_refusals
MAGIC = "seal-results"

_SCHEMA = """
CREATE TABLE seal_meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE methods (
    config_hash TEXT PRIMARY KEY,
    method TEXT NOT NULL,
    config_json TEXT NOT NULL
);
CREATE TABLE trials (
    method TEXT NOT NULL,
    config_hash TEXT NOT NULL REFERENCES methods(config_hash),
    suite TEXT NOT NULL,
    task INTEGER NOT NULL,
    trial INTEGER NOT NULL,
    init_index INTEGER NOT NULL,
    seed INTEGER NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('ok', 'error')),
    success INTEGER NOT NULL,
    steps INTEGER NOT NULL,
    sim_error INTEGER NOT NULL,
    wall_s REAL NOT NULL,
    step_s REAL NOT NULL,
    policy_s REAL NOT NULL,
    verify_wait_s REAL NOT NULL,
    verifier_calls INTEGER NOT NULL,
    input_tokens INTEGER NOT NULL,
    output_tokens INTEGER NOT NULL,
    cost_usd REAL NOT NULL,
    rounds INTEGER NOT NULL,
    fallbacks INTEGER NOT NULL,
    verifier_errors INTEGER NOT NULL DEFAULT 0,
    verifier_unavailable INTEGER NOT NULL DEFAULT 0,
    subplans_audited INTEGER NOT NULL DEFAULT 0,
    subplans_aligned INTEGER NOT NULL DEFAULT 0,
    ended_by TEXT NOT NULL DEFAULT '',
    done_refusals INTEGER NOT NULL DEFAULT 0,
    subplans_json TEXT NOT NULL,
    goal_status_json TEXT NOT NULL,
    trace_path TEXT NOT NULL,
    video_path TEXT NOT NULL,
    error TEXT NOT NULL,
    worker TEXT NOT NULL,
    finished_at REAL NOT NULL,
    PRIMARY KEY (config_hash, suite, task, trial)
);
"""


@dataclass
class TrialRow:
    """One finished trial. ``status='error'`` rows carry the traceback in ``error`` and count
    as failures in reports; ``sim_error`` marks episodes the simulator itself broke."""

    method: str
    config_hash: str
    suite: str
    task: int
    trial: int
    init_index: int
    seed: int
    status: str = "ok"
    success: bool = False
    steps: int = 0
    sim_error: bool = False
    wall_s: float = 0.0
    step_s: float = 0.0  # time in simulator stepping (prediction), from the steerer's timing
    policy_s: float = 0.0  # time in the policy (sampling actions and reasoning)
    verify_wait_s: float = 0.0  # time spent waiting for verdicts
    verifier_calls: int = 0
    input_tokens: int = 0
    output_tokens: int = 0
    cost_usd: float = 0.0
    rounds: int = 0
    fallbacks: int = 0
    verifier_errors: int = 0  # verifications that got no answer (transient errors past their retries)
    verifier_unavailable: bool = False  # in most rounds no verification got an answer: mostly unverified
    subplans_audited: int = 0  # committed sub-plans the oracle could ground (the alignment audit)
    subplans_aligned: int = 0  # of those, the ones whose executed chunks achieved the sub-plan
    ended_by: str = ""  # why the episode stopped (SteerResult.ended_by); "" in rows stored before v5
    done_refusals: int = 0  # times the verifier refused the policy's "the task is complete" (done_check)
    subplans: list = field(default_factory=list)
    goal_status: dict = field(default_factory=dict)
    trace_path: str = ""
    video_path: str = ""
    error: str = ""
    worker: str = ""
    finished_at: float = 0.0
    # Not stored: set when the trial hit an error that stops the whole run (the verifier cannot
    # answer at all). The runner raises it instead of storing the row, so a resumed run redoes it.
    fatal: str = field(default="", compare=False)

    @property
    def key(self) -> tuple[str, str, int, int]:
        return (self.config_hash, self.suite, self.task, self.trial)


_COLUMNS = [f.name for f in fields(TrialRow) if f.name not in ("subplans", "goal_status", "fatal")] + \
    ["subplans_json", "goal_status_json"]


class ResultStore:
    """Open (or create) a results database. Use as a context manager or call ``close``."""

    def __init__(self, path: str | Path, *, create: bool = True):
        self.path = Path(path)
        exists = self.path.exists() and self.path.stat().st_size > 0
        if not exists and not create:
            raise InvalidInput(f"no results database at {self.path}")
        if exists:
            _check_header(self.path)
        # What this call creates (folders, the file) goes again if it fails: a refused command
        # leaves nothing behind.
        made = [p for p in (self.path, *self.path.parents) if not p.exists()]
        self._db = None
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(self.path, timeout=30, isolation_level=None)
            if exists:
                self._check_meta()
                if create:  # a writer: find a read-only file or folder now, not at the first finished trial
                    self._db.execute("BEGIN IMMEDIATE")
                    self._db.execute("ROLLBACK")
            else:
                self._create()
        except (OSError, sqlite3.OperationalError) as exc:
            self._abandon(made)
            if exists:
                raise InvalidInput(f"cannot open the results database {self.path} ({exc}): the file and its folder "
                                   "must be writable (SQLite keeps its log beside the file)") from None
            raise InvalidInput(f"cannot create the results database {self.path} ({exc}); pass a --db in a folder "
                               "you can write to") from None
        except BaseException:
            self._abandon(made)
            raise

    def _abandon(self, made: list[Path]) -> None:
        if self._db is not None:
            self._db.close()
        for p in made:  # the file (and SQLite's side files) first, then its new folders, innermost first
            with contextlib.suppress(OSError):
                if p == self.path:
                    for side in ("-wal", "-shm", "-journal"):
                        Path(f"{p}{side}").unlink(missing_ok=True)
                    p.unlink(missing_ok=True)
                else:
                    p.rmdir()

    # ---- lifecycle ------------------------------------------------------------------------
    def _create(self) -> None:
        with self._tx():
            for stmt in filter(None, (s.strip() for s in _SCHEMA.split(";"))):
                self._db.execute(stmt)
            self._db.execute("INSERT INTO seal_meta VALUES ('magic', ?), ('schema_version', ?), ('created', ?)",
                             (MAGIC, str(SCHEMA_VERSION), time.strftime("%Y-%m-%dT%H:%M:%S")))
        self._db.execute("PRAGMA journal_mode=WAL")

    def _check_meta(self) -> None:
        try:
            meta = dict(self._db.execute("SELECT key, value FROM seal_meta").fetchall())
        except sqlite3.DatabaseError as exc:  # no such table, malformed file...
            if _cannot_access(exc):  # a file or folder this process may not write (SQLite's log lives beside it)
                raise
            raise InvalidInput(f"{self.path} is not a SEAL results database ({exc}); "
                               "pass a new file name or one written by `seal eval`") from None
        if meta.get("magic") != MAGIC:
            raise InvalidInput(f"{self.path} is not a SEAL results database (no {MAGIC!r} marker)")
        version = int(meta.get("schema_version", "0"))
        if version > SCHEMA_VERSION:
            raise InvalidInput(f"{self.path} has results schema v{version}; this seal reads up to "
                               f"v{SCHEMA_VERSION} (upgrade seal)")
        try:
            self._db.execute("PRAGMA quick_check").fetchone()
        except sqlite3.DatabaseError as exc:
            raise InvalidInput(f"{self.path} is corrupted ({exc}); it was left untouched") from None
        if version < SCHEMA_VERSION:
            self._migrate(version)

    def _migrate(self, version: int) -> None:
        """Bring an older database of ours up to date, in one transaction."""
        with self._tx():
            if version < 2:
                self._db.execute("ALTER TABLE trials ADD COLUMN policy_s REAL NOT NULL DEFAULT 0")
            if version < 3:
                self._db.execute("ALTER TABLE trials ADD COLUMN verifier_errors INTEGER NOT NULL DEFAULT 0")
                self._db.execute("ALTER TABLE trials ADD COLUMN verifier_unavailable INTEGER NOT NULL DEFAULT 0")
            if version < 4:  # older trials were not audited: 0 of 0, shown as no figure
                self._db.execute("ALTER TABLE trials ADD COLUMN subplans_audited INTEGER NOT NULL DEFAULT 0")
                self._db.execute("ALTER TABLE trials ADD COLUMN subplans_aligned INTEGER NOT NULL DEFAULT 0")
            if version < 5:  # older rows keep "": their traces may still say (the report looks there)
                self._db.execute("ALTER TABLE trials ADD COLUMN ended_by TEXT NOT NULL DEFAULT ''")
            if version < 6:  # older rows never asked: 0
                self._db.execute("ALTER TABLE trials ADD COLUMN done_refusals INTEGER NOT NULL DEFAULT 0")
            self._db.execute("UPDATE seal_meta SET value = ? WHERE key = 'schema_version'", (str(SCHEMA_VERSION),))

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> "ResultStore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _tx(self):
        return _Transaction(self._db)

    def check_step_cap(self, max_steps: int | None) -> None:
        """One database, one episode cap. The cap is not part of a method's identity, so a trial
        run with ``--max-steps 10`` would otherwise count as done for a run at the suite's limit
        (and its row would read as a real result). The first run on a database sets it; a
        database from before this check holds full-length trials."""
        wanted = "suite" if max_steps is None else str(int(max_steps))
        row = self._db.execute("SELECT value FROM seal_meta WHERE key = 'max_steps'").fetchone()
        if row is None:
            has_trials = self._db.execute("SELECT 1 FROM trials LIMIT 1").fetchone() is not None
            row = ("suite" if has_trials else wanted,)
            with self._tx():
                self._db.execute("INSERT INTO seal_meta VALUES ('max_steps', ?)", row)
        if row[0] != wanted:
            def say(cap: str) -> str:
                return "the suite's step limit" if cap == "suite" else f"--max-steps {cap}"

            raise InvalidInput(f"{self.path} holds trials run with {say(row[0])}; this run asks for {say(wanted)}. "
                               "Episodes of another length are other trials: use another --db")

    # ---- writing --------------------------------------------------------------------------
    def register_method(self, config_hash: str, method: str, config: dict) -> None:
        """Remember what a config hash means, so reports can show it."""
        with self._tx():
            self._db.execute("INSERT OR IGNORE INTO methods VALUES (?, ?, ?)",
                             (config_hash, method, json.dumps(config, sort_keys=True)))

    def add(self, row: TrialRow, *, replace_error: bool = False) -> bool:
        """Store a finished trial; returns False (and stores nothing) if it is already there.
        ``replace_error``: a stored error row of the same trial gives way to this one (in one
        transaction, so the error stays on record until its replacement is stored)."""
        values = asdict(row)
        values["subplans_json"] = json.dumps(values.pop("subplans"))
        values["goal_status_json"] = json.dumps(values.pop("goal_status"))
        values["success"], values["sim_error"] = int(bool(row.success)), int(bool(row.sim_error))
        values["verifier_unavailable"] = int(bool(row.verifier_unavailable))
        values["finished_at"] = values["finished_at"] or time.time()
        with self._tx():
            if replace_error:
                self._db.execute("DELETE FROM trials WHERE config_hash = ? AND suite = ? AND task = ? AND trial = ? "
                                 "AND status = 'error'", (row.config_hash, row.suite, row.task, row.trial))
            cur = self._db.execute(
                f"INSERT OR IGNORE INTO trials ({', '.join(_COLUMNS)}) VALUES ({', '.join('?' * len(_COLUMNS))})",
                [values[c] for c in _COLUMNS])
        return cur.rowcount == 1

    # ---- reading --------------------------------------------------------------------------
    def done_keys(self, *, errors: bool = True) -> set[tuple[str, str, int, int]]:
        """Keys of the stored trials (``errors=False``: of those that did not end in an error)."""
        sql = "SELECT config_hash, suite, task, trial FROM trials" + ("" if errors else " WHERE status != 'error'")
        return {tuple(r) for r in self._db.execute(sql)}

    def rows(self, *, suite: str | None = None, method: str | None = None) -> list[TrialRow]:
        sql, args = f"SELECT {', '.join(_COLUMNS)} FROM trials", []
        where = [(c, v) for c, v in (("suite", suite), ("method", method)) if v is not None]
        if where:
            sql += " WHERE " + " AND ".join(f"{c} = ?" for c, _ in where)
            args = [v for _, v in where]
        out = []
        for rec in self._db.execute(sql + " ORDER BY suite, task, method, trial", args):
            d = dict(zip(_COLUMNS, rec))
            d["subplans"] = json.loads(d.pop("subplans_json"))
            d["goal_status"] = json.loads(d.pop("goal_status_json"))
            d["success"], d["sim_error"] = bool(d["success"]), bool(d["sim_error"])
            d["verifier_unavailable"] = bool(d["verifier_unavailable"])
            out.append(TrialRow(**d))
        return out

    def methods(self) -> dict[str, tuple[str, dict]]:
        """config hash -> (method name, config)."""
        return {h: (m, json.loads(c)) for h, m, c in self._db.execute("SELECT * FROM methods")}

    def count(self) -> int:
        return self._db.execute("SELECT COUNT(*) FROM trials").fetchone()[0]


class _Transaction:
    """BEGIN IMMEDIATE ... COMMIT, rolled back on error (autocommit connection)."""

    def __init__(self, db: sqlite3.Connection):
        self.db = db

    def __enter__(self):
        self.db.execute("BEGIN IMMEDIATE")
        return self.db

    def __exit__(self, exc_type, *_):
        self.db.execute("ROLLBACK" if exc_type else "COMMIT")


def _cannot_access(exc: sqlite3.DatabaseError) -> bool:
    """SQLite's way of saying a file or folder may not be opened or written (not that it is not ours)."""
    return isinstance(exc, sqlite3.OperationalError) and any(
        text in str(exc) for text in ("readonly", "unable to open", "disk I/O"))


def _check_header(path: Path) -> None:
    """Refuse a file that is not SQLite at all before sqlite3 gets a chance to touch it."""
    with open(path, "rb") as f:
        head = f.read(16)
    if head != b"SQLite format 3\x00":
        raise InvalidInput(f"{path} is not a SQLite file (a SEAL results database is); it was left untouched. "
                           "Pass a new file name or one written by `seal eval`.")
