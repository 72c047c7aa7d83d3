"""Stage bookkeeping: skip a stage whose inputs did not change, redo one whose inputs did.

Each stage owns a folder under the run directory and a record `<stage>/stage.json` holding the
hash of everything it depends on (its config section and the hashes of the stages before it)
and whether it finished. A stage whose record matches and says finished is skipped; a stage
that started but did not finish is run again in the same folder, where the stage's own
resumable machinery (the renderer's per-frame resume, training's last checkpoint) continues
the work instead of starting over.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from segmin.common.atomic import write_json


def hash_inputs(*parts: Any) -> str:
    """A stable sha256 of JSON-serialisable parts (dict key order does not matter)."""
    text = json.dumps(parts, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


@dataclass
class StageRecord:
    """What a stage folder says about itself."""

    name: str
    input_hash: str
    finished: bool
    seconds: float = 0.0
    outputs: dict[str, Any] | None = None


class StageCache:
    """Reads and writes stage records in a run directory."""

    def __init__(self, run_dir: str | Path) -> None:
        self.run_dir = Path(run_dir)

    def folder(self, stage: str) -> Path:
        return self.run_dir / stage

    def record(self, stage: str) -> StageRecord | None:
        path = self.folder(stage) / "stage.json"
        if not path.is_file():
            return None
        try:
            raw = json.loads(path.read_text())
            return StageRecord(**raw)
        except (json.JSONDecodeError, TypeError) as exc:
            raise ValueError(f"{path}: unreadable stage record ({exc}); remove it to rerun the stage") from exc

    def started(self, stage: str, input_hash: str) -> None:
        write_json(
            self.folder(stage) / "stage.json",
            {"name": stage, "input_hash": input_hash, "finished": False, "seconds": 0.0, "outputs": None},
        )

    def finished(self, stage: str, input_hash: str, seconds: float, outputs: dict[str, Any]) -> None:
        write_json(
            self.folder(stage) / "stage.json",
            {
                "name": stage,
                "input_hash": input_hash,
                "finished": True,
                "seconds": round(seconds, 2),
                "outputs": outputs,
            },
        )

    def invalidate(self, stage: str) -> None:
        """Mark a stage as not finished (its work folder stays, so resumable work is kept)."""
        record = self.record(stage)
        if record is not None:
            self.started(stage, record.input_hash)


class Timer:
    """Wall-clock seconds since construction."""

    def __init__(self) -> None:
        self.start = time.perf_counter()

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self.start
