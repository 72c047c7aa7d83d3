"""Jobs keyed by what their run depends on, run against the run store: the core every sweep shares.

A robustness sweep (one field, one parameter at a time) and a family comparison (world seeds x
settings) differ in what they vary, not in how they run: each job's key is a hash of its world,
nav config, model, method and seed (`run_key`); a run stored under its key in `OUT/runs/` is read
back instead of run again (`run_keyed_jobs`), so both resume after a kill and rerun only what a
changed spec changes. A world that is not a shipped one is written beside the runs
(`write_world`) so that each run can load it by path, as nav-eval loads a user's field.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, TypeVar

import yaml

from segmin.common.atomic import write_text
from segmin.common.executor import Executor
from segmin.common.outputs import check_output_dir
from segmin.nav_eval.evaluation.evaluate import execute_jobs
from segmin.nav_eval.evaluation.records import Job, RunResult
from segmin.nav_eval.evaluation.run_store import RUNS_FOLDER, digest, model_identity, store_run, stored_runs
from segmin.nav_eval.sim.config import NavEvalConfig
from segmin.nav_eval.sim.factories import make_segmenter

S = TypeVar("S", bound=Any)


def with_command_line(spec: S, model: str | None, runs: int | None) -> S:
    """`spec` (a sweep spec dataclass) with `--model` and `--runs` in place of its own where given;
    its own checks run again, so a bad `--runs` is named as the flag."""
    try:
        return dataclasses.replace(spec, **{k: v for k, v in (("model", model), ("runs", runs)) if v is not None})
    except ValueError as exc:
        raise ValueError(f"--runs: {exc}") from exc


def prepare_runs(model: str, workers: int, out_dir: str | Path) -> tuple[Path, str]:
    """Checked before any run: the worker count, the model (its file loaded and checked) and the
    output folder. Returns the folder and the model's identity for the run keys."""
    if workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    if model != "oracle":
        make_segmenter(model, threads=1)
    return check_output_dir(out_dir, "--out"), model_identity(model)


def run_key(world: dict, config: dict, model_id: str, method: str, seed: int) -> str:
    """The run store key of one run: its world and nav config (as plain data), the model's
    identity (`run_store.model_identity`), the method and the seed."""
    setting = digest({"world": world, "config": config})
    return digest({"setting": setting, "model": model_id, "method": method, "seed": seed})


def write_world(path: Path, world: dict, header: str) -> str:
    """`world` (a world spec as plain data) as YAML at `path` under a one-line comment; the path
    as a `--fields` entry."""
    write_text(path, f"# {header}\n" + yaml.safe_dump(world, sort_keys=False))
    return str(path)


@dataclasses.dataclass
class KeyedOutcome:
    """Every job's result by key (read back or run now), and what this call did."""

    results: dict[str, RunResult]
    executed: int
    reused: int
    errored: list[RunResult]


def run_keyed_jobs(
    out: Path,
    jobs: dict[str, Job],
    model: str,
    config: NavEvalConfig,
    workers: int,
    *,
    force: bool,
    progress: bool,
    desc: str,
    executor: Executor,
) -> KeyedOutcome:
    """Run the jobs whose key has no stored run in `out/runs` (all of them with `force`), storing
    each as it finishes; runs that raised are returned in `errored`, not stored (they run again
    next time). `config` is the workers' default; each job carries its own."""
    cached = {} if force else stored_runs(out / RUNS_FOLDER, jobs, RunResult.from_stored)
    todo = [job for key, job in jobs.items() if key not in cached]
    key_of = {id(job): key for key, job in jobs.items()}
    new: dict[str, RunResult] = {}
    errored: list[RunResult] = []

    def done(job: Job, result: RunResult) -> None:
        if result.reason == "error":
            errored.append(result)
            return
        key = key_of[id(job)]
        new[key] = result
        store_run(out / RUNS_FOLDER, key, result)

    execute_jobs(todo, model, config, workers, done, progress=progress, desc=desc, executor=executor)
    return KeyedOutcome({**cached, **new}, len(new), len(cached), errored)
