"""Finished runs kept one file each, so an interrupted evaluation resumes where it stopped.

`segmin robustness` and `segmin nav-eval` write each run the moment it finishes, atomically, to
`OUT/runs/<key>.json` (Python's JSON: NaN and Infinity as such), the key a hash of everything
the run depends on (world, nav config, model file content, method, seed, ...). A later call
skips the jobs whose file it can read back: a killed evaluation loses at most the runs in
progress, and a changed setting reruns only what it changes. Runs that raised are not stored:
they are run again next time.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

from segmin.common.atomic import write_json
from segmin.nav_eval.runtime.segmenter import runtime_model_file

RUNS_FOLDER = "runs"
T = TypeVar("T")


def digest(obj: Any) -> str:
    """A short stable hash of plain data (sorted-key JSON)."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def model_sha256(model: str) -> str | None:
    """The sha256 of the file the runs use for `model` (a path, or the file the runtime picks for
    a shipped name: `runtime_model_file`); None for 'oracle'."""
    return None if model == "oracle" else _sha256(runtime_model_file(model))


def model_identity(model: str) -> str:
    """'oracle', or the exported file's content hash: a moved file keeps its runs, a new file
    written over the old one at the same path does not."""
    if model == "oracle":
        return model
    path = runtime_model_file(model)  # resolved once: a shipped name's choice logs once
    return f"{'tflite' if path.suffix == '.tflite' else 'onnx'}:{_sha256(path)[:16]}"


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def store_run(folder: Path, key: str, result: Any, *, trajectory: bool = False) -> None:
    """`result` (a `RunResult`) as `folder/<key>.json`; with `trajectory`, its path too (what a
    resumed nav-eval's figures draw)."""
    entry: dict[str, Any] = {"key": key, "result": result.row()}
    if trajectory and result.trajectory is not None:
        entry["trajectory"] = result.trajectory.to_dict()
    write_json(folder / f"{key}.json", entry)


def stored_runs(folder: Path, keys: Iterable[str], read: Callable[[dict[str, Any]], T]) -> dict[str, T]:
    """`read(entry)` of each key's stored run in `folder` (`RunResult.from_stored`); a missing or
    unreadable file is left out, so that run is done again."""
    found = {}
    for key in set(keys):
        path = folder / f"{key}.json"
        if not path.is_file():
            continue
        try:
            found[key] = read(json.loads(path.read_text()))
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return found
