"""Stage bookkeeping: skip a stage whose inputs did not change, redo one whose inputs did.

Each stage owns a folder under the run directory and a record `<stage>/stage.json` holding the
hash of everything it depends on (its config section and the hashes of the stages before it)
and whether it finished. A stage that started but did not finish is run again in the same
folder, where the stage's own resumable machinery (the renderer's per-frame resume, training's
last checkpoint) continues the work instead of starting over.

A finished record also lists the stage's output files with their size and sha256 (`files`),
and the fingerprint of each earlier stage's files as it read them (`reads`). The record alone
does not make a stage done: its files must still be there as recorded, and the stages it read
must still hold what it read (a file deleted, truncated or rebuilt since means it runs again).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from segmin.common.atomic import write_json


def hash_inputs(*parts: Any) -> str:
    """A stable sha256 of JSON-serialisable parts (dict key order does not matter)."""
    text = json.dumps(parts, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


RECORD = "stage.json"


def file_digest(path: Path) -> str:
    """sha256 of a file's content, read in 1 MiB blocks (checkpoints and frame folders are large)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def file_manifest(run_dir: Path, paths: Iterable[Path]) -> dict[str, list[Any]]:
    """{path relative to `run_dir`: [size in bytes, sha256]} of every file in `paths` (files, or
    folders read recursively; stage records left out). A path that does not exist is an error:
    a stage that says it finished without an output it names has not."""
    root = Path(run_dir).resolve()
    files: dict[str, list[Any]] = {}
    for path in map(Path, paths):
        if not path.exists():
            raise FileNotFoundError(f"{path}: a stage output is missing at the end of its stage")
        found = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
        for file in found:
            if file.name != RECORD:
                files[file.resolve().relative_to(root).as_posix()] = [file.stat().st_size, file_digest(file)]
    return files


def changed_file(run_dir: Path, files: dict[str, list[Any]]) -> str | None:
    """Why the recorded `files` are no longer what a stage left (the first difference), or None.

    Sizes first, for every file (a stat each), then the content: a deleted or truncated output
    is found without hashing the rest."""
    root = Path(run_dir)
    for name, (size, _) in files.items():
        path = root / name
        if not path.is_file():
            return f"{name} is missing"
        if (now := path.stat().st_size) != size:
            return f"{name} is {now} bytes, {size} when its stage finished"
    for name, (_, digest) in files.items():
        if file_digest(root / name) != digest:
            return f"{name} changed since its stage finished (same size, other content)"
    return None


@dataclass
class StageRecord:
    """What a stage folder says about itself (`files` and `reads`: see the module docstring;
    None in a record of an unfinished stage, or of one written before they were recorded)."""

    name: str
    input_hash: str
    finished: bool
    seconds: float = 0.0
    outputs: dict[str, Any] | None = None
    files: dict[str, list[Any]] | None = None
    reads: dict[str, str | None] | None = None

    @property
    def digest(self) -> str:
        """Fingerprint of the stage's output files, which a later stage records as what it read."""
        return hash_inputs(self.files)


class StageCache:
    """Reads and writes stage records in a run directory."""

    def __init__(self, run_dir: str | Path) -> None:
        self.run_dir = Path(run_dir)

    def folder(self, stage: str) -> Path:
        return self.run_dir / stage

    def record(self, stage: str) -> StageRecord | None:
        path = self.folder(stage) / RECORD
        if not path.is_file():
            return None
        try:
            raw = json.loads(path.read_text())
            return StageRecord(**raw)
        except (json.JSONDecodeError, TypeError) as exc:
            raise ValueError(f"{path}: unreadable stage record ({exc}); remove it to rerun the stage") from exc

    def started(self, stage: str, input_hash: str) -> None:
        write_json(
            self.folder(stage) / RECORD,
            {"name": stage, "input_hash": input_hash, "finished": False, "seconds": 0.0, "outputs": None},
        )

    def finished(
        self,
        stage: str,
        input_hash: str,
        seconds: float,
        outputs: dict[str, Any],
        files: dict[str, list[Any]],
        reads: dict[str, str | None],
    ) -> None:
        write_json(
            self.folder(stage) / RECORD,
            {
                "name": stage,
                "input_hash": input_hash,
                "finished": True,
                "seconds": round(seconds, 2),
                "outputs": outputs,
                "files": files,
                "reads": reads,
            },
        )

    def digests(self, stages: Iterable[str]) -> dict[str, str | None]:
        """The current fingerprint of each stage's files (None for a stage without a finished record)."""
        records = {stage: self.record(stage) for stage in stages}
        return {
            stage: record.digest if record is not None and record.finished and record.files is not None else None
            for stage, record in records.items()
        }

    def stale(self, record: StageRecord) -> str | None:
        """Why a finished record no longer describes its stage's work, or None when it still does."""
        if record.files is None:
            return "its record lists no output files (written by an older segmin)"
        reads = record.reads or {}
        for stage, now in self.digests(reads).items():
            if now != reads[stage]:
                return f"{stage} changed since it ran"
        return changed_file(self.run_dir, record.files)


class Timer:
    """Wall-clock seconds since construction."""

    def __init__(self) -> None:
        self.start = time.perf_counter()

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self.start
