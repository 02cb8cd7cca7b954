"""What every learned model's checkpoint directory shares: a manifest that vouches for its files.

A checkpoint is a directory. Its ``manifest.json`` is written last (the commit) and records the
kind of model, a format number, and the sha256 and size of every file the model is built from:

    {"kind": "seal-vla", "format": 1, "files": {"model.safetensors": {"sha256": ..., "bytes": ...},
     "config.json": {...}, ...}, ...what the trainer adds (data, command, steps, held-out figures)}

`verify` is the one door every load path goes through (``seal run``, ``eval``, ``serve``, ``bench``,
Ray and pool workers alike): the manifest must be there and parse, name the expected kind and list
every required file, and every listed file must have exactly the recorded size and sha256. Anything
else is an `InvalidInput` naming the file and what is wrong, which the CLI prints as
``seal: error: ...`` with exit status 2. A damaged file is caught before a byte of it is parsed,
so no corrupted weights ever reach a model, and a model's identity in a results store (`identity`)
is taken from the bytes that were checked, never from what a manifest merely claims.

Hashing a shipped checkpoint costs ~20 ms per 10 MB; results are memoised per file by path, size,
inode and modification time, so the many identity lookups of one run hash each file once.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from seal.errors import InvalidInput

MANIFEST = "manifest.json"


def atomic_write(path: Path, write) -> None:
    """``write(tmp)`` then rename over ``path``: a crash leaves the old file or the new, never half."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    write(tmp)
    os.replace(tmp, path)


def file_digests(path: Path) -> tuple[str, str]:
    """(sha256, sha1) of a file's bytes, memoised while the file is unchanged."""
    st = Path(path).stat()
    return _digests(str(Path(path).resolve()), st.st_size, st.st_ino, st.st_mtime_ns)


@lru_cache(maxsize=256)
def _digests(path: str, size: int, inode: int, mtime_ns: int) -> tuple[str, str]:
    sha256, sha1 = hashlib.sha256(), hashlib.sha1()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            sha256.update(block)
            sha1.update(block)
    return sha256.hexdigest(), sha1.hexdigest()


def write_manifest(directory: Path, *, kind: str, files: list[str], format: int = 1, extra: dict | None = None) -> dict:
    """Record ``files`` (names inside ``directory``) with their sha256 and size; returns the manifest."""
    directory = Path(directory)
    record = {"kind": kind, "format": format,
              "files": {name: {"sha256": file_digests(directory / name)[0], "bytes": (directory / name).stat().st_size}
                        for name in files}}
    record |= {k: v for k, v in (extra or {}).items() if k not in record}
    atomic_write(directory / MANIFEST, lambda p: p.write_text(json.dumps(record, indent=2) + "\n"))
    return record


def amend_manifest(directory: Path, fields: dict) -> dict:
    """Add fields to a manifest (where shipped weights came from, what reports call them). The manifest
    vouches for the other files, not for itself, so digests and verification stay as they were."""
    path = Path(directory) / MANIFEST
    manifest = json.loads(path.read_text()) | fields
    atomic_write(path, lambda p: p.write_text(json.dumps(manifest, indent=2) + "\n"))
    return manifest


def read_manifest(directory: Path, *, kind: str) -> dict:
    """The parsed manifest of a checkpoint of ``kind`` (nothing about its files is checked yet)."""
    directory = Path(directory)
    file = directory / MANIFEST
    if not file.is_file():
        raise InvalidInput(f"{directory} is not a complete {kind} checkpoint: {MANIFEST} is missing (an interrupted "
                           f"save, a copy that left it out, or not a checkpoint directory)")
    try:
        manifest = json.loads(file.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InvalidInput(f"{file} is not valid JSON ({exc})") from None
    if not isinstance(manifest, dict):
        raise InvalidInput(f"{file} must hold a JSON object")
    if manifest.get("kind") != kind:
        raise InvalidInput(f"{file} describes a {manifest.get('kind')!r} checkpoint; this loader reads {kind!r}")
    return manifest


def verify(directory: Path, *, kind: str, required: tuple[str, ...]) -> dict:
    """Check a checkpoint directory against its manifest; returns the manifest.

    Every name in ``required`` must be listed, and every listed file must be present with the
    recorded size and sha256."""
    directory = Path(directory)
    if not directory.is_dir():
        raise InvalidInput(f"no {kind} checkpoint directory at {directory}")
    manifest = read_manifest(directory, kind=kind)
    files = manifest.get("files")
    if not isinstance(files, dict) or not files:
        raise InvalidInput(f"{directory / MANIFEST} lists no files with their sha256 and size, so nothing vouches "
                           f"for the weights; re-save the checkpoint with this version of seal")
    unlisted = [name for name in required if name not in files]
    if unlisted:
        raise InvalidInput(f"{directory / MANIFEST} does not vouch for {', '.join(unlisted)}; it lists "
                           f"{', '.join(sorted(files))}")
    for name, entry in sorted(files.items()):
        path = directory / name
        if not isinstance(entry, dict) or not isinstance(entry.get("sha256"), str) or not isinstance(entry.get("bytes"), int):
            raise InvalidInput(f"{directory / MANIFEST}: the entry for {name} needs a sha256 string and a bytes count")
        if not path.is_file():
            raise InvalidInput(f"checkpoint {directory} lacks {name}, which its manifest lists")
        size = path.stat().st_size
        if size != entry["bytes"]:
            raise InvalidInput(f"{path} is {size} bytes but the manifest says {entry['bytes']}: the file is truncated "
                               f"or was replaced")
        if file_digests(path)[0] != entry["sha256"]:
            raise InvalidInput(f"{path} does not match the sha256 in its manifest: the file is corrupt or was replaced")
    return manifest


def identity(directory: Path, *, kind: str, required: tuple[str, ...], files: tuple[str, ...],
             algorithm: str = "sha256") -> str:
    """A checkpoint's name in a results store: 12 hex digits over the verified bytes of ``files``.

    One file with sha256 is the digest its manifest records (the VLA's weights); several, or sha1,
    hash the files' bytes in order (the learned verifier's weights + config, as results stores have
    named it from the start)."""
    directory = Path(directory)
    verify(directory, kind=kind, required=required)
    if algorithm == "sha256" and len(files) == 1:
        return file_digests(directory / files[0])[0][:12]
    paths = [(directory / name).resolve() for name in files]
    return _joint_digest(algorithm, tuple((str(p), *_stamp(p)) for p in paths))


def _stamp(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_size, st.st_ino, st.st_mtime_ns


@lru_cache(maxsize=256)
def _joint_digest(algorithm: str, files: tuple[tuple[str, int, int, int], ...]) -> str:
    """One hash over several files' bytes in order, memoised while none of them changes (reports name
    many rows by the same few checkpoints)."""
    h = hashlib.new(algorithm)
    for path, *_ in files:
        with open(path, "rb") as f:
            h.update(f.read())
    return h.hexdigest()[:12]


@dataclass(frozen=True)
class CheckpointFormat:
    """One kind of checkpoint directory: its manifest's kind, the files the manifest must vouch for,
    and the files whose bytes name it in a results store (with which hash). The one way every
    plug-in with weights (the VLA, the learned verifier, the V-GPS value function) checks and names
    its checkpoint."""

    kind: str
    required: tuple[str, ...]
    named_by: tuple[str, ...]
    algorithm: str = "sha256"

    def verify(self, directory: Path) -> dict:
        return verify(directory, kind=self.kind, required=self.required)

    def digest(self, directory: Path) -> str:
        """12 hex digits over the verified bytes of ``named_by`` (`identity`)."""
        return identity(directory, kind=self.kind, required=self.required, files=self.named_by,
                        algorithm=self.algorithm)

    def install(self, source: Path, target: Path, fields: dict) -> Path:
        """Copy the checkpoint at ``source`` to ``target`` (which must not exist) and add ``fields`` to the
        copy's manifest (where it came from, why it ships). The source is checked before a byte is copied
        and the copy before it takes its name, so a damaged checkpoint never ships and an interrupted
        copy leaves nothing under ``target`` (it is staged beside it and renamed last)."""
        source, target = Path(source), Path(target)
        self.digest(source)
        if target.exists():
            raise InvalidInput(f"{target} exists already; a shipped checkpoint is never copied over")
        staging = target.with_name(f".{target.name}.staging")
        shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir(parents=True)
        for name in (*self.required, MANIFEST):
            shutil.copy2(source / name, staging / name)
        amend_manifest(staging, fields)
        self.digest(staging)
        staging.rename(target)
        return target


def set_aside(current: Path, kept: Path, shipped: dict) -> Path:
    """Move the shipped checkpoint ``current`` to ``kept`` (a name it stays loadable under, so the
    tables made with it stay reproducible) and merge ``shipped`` (its label from now on, what
    replaced it) into its manifest's ``shipped`` record. Its files, and so its digest, are unchanged."""
    current, kept = Path(current), Path(kept)
    if kept.exists():
        raise InvalidInput(f"{kept} exists already; choose another name to keep {current} under")
    shutil.move(str(current), str(kept))
    previous = json.loads((kept / MANIFEST).read_text()).get("shipped", {})
    amend_manifest(kept, {"shipped": {**previous, **shipped}})
    return kept
