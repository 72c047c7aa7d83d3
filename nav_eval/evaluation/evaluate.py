"""Run the evaluation matrix (fields x methods x runs) in worker processes and write the outputs.

Public entry point for the pipeline: `run_evaluation(model, fields, methods, runs, out_dir,
workers, config) -> list[RunResult]`.

Each run is one job. A `Worker` builds its own pybullet DIRECT client per field, its own
segmenter and navigators, and returns a `RunResult`; with several workers each lives in its own
spawned process (`segmin.common.processes`). An exception inside a run becomes a failure
row (reason "error", with the exception text); a crashed worker process fails its run the same
way. Seeds: the start noise and the depth noise of run k in a field depend on (seed, field, k)
only, so every method starts from the same pose with the same noise (a paired comparison).
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import os
import shutil
import time
import traceback
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.config import from_dict, to_dict
from segmin.common.executor import LOCAL, Executor
from segmin.common.outputs import check_output_dir
from segmin.nav_eval.evaluation.metrics import METRIC_KEYS, compute_metrics
from segmin.nav_eval.evaluation.records import Job, RunResult
from segmin.nav_eval.evaluation.run_store import (
    RUNS_FOLDER,
    digest,
    model_identity,
    model_sha256,
    store_run,
    stored_runs,
)
from segmin.nav_eval.runtime.methods import METHODS
from segmin.nav_eval.runtime.shipped_models import resolve_model
from segmin.nav_eval.sim.config import NavEvalConfig, load_nav_config
from segmin.nav_eval.sim.factories import (
    FieldContext,
    field_label,
    follower_config,
    make_follower,
    make_navigator,
    make_segmenter,
    make_simulator,
)
from segmin.nav_eval.sim.faults import fault_metrics
from segmin.nav_eval.sim.mask_closing import with_closing
from segmin.nav_eval.sim.mask_dropout import with_dropout
from segmin.nav_eval.sim.protocols import FrameSegmenter

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------------------
# Field resolution and seeds
# ---------------------------------------------------------------------------------------------


def resolve_fields(fields: str | list[str] | tuple[str, ...]) -> list[str]:
    """'all' -> the five test fields; 'a,b' or a list -> names or world spec paths (checked)."""
    from segmin.data.synth.spec import TEST_FIELDS, load_world_spec

    items = [f.strip() for f in fields.split(",")] if isinstance(fields, str) else [str(f) for f in fields]
    items = [f for f in items if f]
    if items == ["all"]:
        items = list(TEST_FIELDS)
    if not items:
        raise ValueError("--fields: no field given")
    for item in items:
        spec = load_world_spec(item)
        if spec.name.startswith("train_"):
            raise ValueError(f"--fields: {item!r} is a training world ({spec.name}); evaluate only on test fields")
    return items


def run_seed(base_seed: int, field: str, run: int) -> int:
    """Seed of run `run` in `field` (the same for every method: paired starts)."""
    key = zlib.crc32(field_label(field).encode())
    return int(np.random.SeedSequence([int(base_seed), key, int(run)]).generate_state(1)[0])


class RunErrors(RuntimeError):
    """Some runs raised (a bug or a broken setup, not bad driving): their numbers are not results."""

    def __init__(self, errored: list[RunResult], total: int, where: str = "") -> None:
        first = errored[0]
        detail = first.error.splitlines()[0] if first.error else "no message"
        super().__init__(
            f"{where + ': ' if where else ''}{len(errored)} of {total} run(s) raised, e.g. "
            f"{first.field}/{first.method}/run {first.run}: {detail}"
        )
        self.errored = errored


def raise_for_errors(results: list[RunResult], where: str = "") -> None:
    """RunErrors when any run raised. A run that fails by driving badly (collision, timeout,
    stall) is a result and passes; a run whose code raised is an error and must not be
    reported, cached or scored as if it were one."""
    errored = [r for r in results if r.reason == "error"]
    if errored:
        raise RunErrors(errored, len(results), where)


def preflight(model: str, fields: list[str], methods: list[str], config: NavEvalConfig) -> None:
    """Check the model and every field's navigator settings before the first run.

    Without this a foreign ONNX file, `navigator.v_max=-1` or a bad depth threshold makes every
    run raise inside the workers, which only shows up as a table of error rows at the end.
    Raises ValueError naming the file or the setting.
    """
    from segmin.data.synth.spec import load_world_spec

    if str(model) != "oracle":
        make_segmenter(str(model), threads=1)  # loads and checks the file: metadata, graph in/out
    for f in fields:
        check_navigators(load_world_spec(f), field_label(f), methods, config)


def check_navigators(spec: Any, label: str, methods: list[str], config: NavEvalConfig) -> None:
    """Build each method's navigator for the field `spec` (its depth threshold) under `config`."""
    threshold = config.depth_threshold(spec.name, spec.family)
    for method in methods:
        try:
            make_navigator(method, threshold, config)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"navigator settings for {label} / {method} (depth threshold "
                f"{threshold!r}, follower {config.follower}): {exc}"
            ) from exc


def parse_methods(methods: str | list[str] | tuple[str, ...]) -> list[str]:
    items = [m.strip().lower() for m in methods.split(",")] if isinstance(methods, str) else list(methods)
    bad = [m for m in items if m not in METHODS]
    if bad or not items:
        raise ValueError(f"--methods: unknown {bad}; choose from {list(METHODS)}")
    return items


# ---------------------------------------------------------------------------------------------
# Inside a worker
# ---------------------------------------------------------------------------------------------


class Worker:
    """Per-process state: fields built on first use (the last few kept), one segmenter."""

    # Built fields kept per worker. Jobs come field by field, so one would do for a matrix; a
    # sweep has dozens of field variants, and each built world holds its own pybullet client.
    KEEP_FIELDS = 2

    def __init__(self, model: str, config: NavEvalConfig, threads: int = 1) -> None:
        self.model = str(model)
        self.config = config
        self.threads = threads
        self._segmenter: FrameSegmenter | None = None
        self._fields: dict[tuple, FieldContext] = {}

    @classmethod
    def from_plain(cls, model: str, config: dict, threads: int) -> Worker:
        """A worker for a config given as plain data (`to_dict`): how a worker process gets it."""
        return cls(model, from_dict(NavEvalConfig, config), threads)

    def field(self, name: str, config: NavEvalConfig | None = None) -> FieldContext:
        """The field built for `config` (camera size and gap; the worker's config by default)."""
        config = config or self.config
        key = (name, config.perception.width, config.perception.height, config.run.gap)
        ctx = self._fields.pop(key, None) or FieldContext(name, config)
        self._fields[key] = ctx  # most recently used last
        while len(self._fields) > self.KEEP_FIELDS:
            self._fields.pop(next(iter(self._fields))).close()
        return ctx

    @property
    def segmenter(self) -> FrameSegmenter:
        """The model's segmenter, loaded on first use and kept for every run of this worker."""
        if self._segmenter is None:
            self._segmenter = make_segmenter(self.model, self.threads)
        return self._segmenter

    def close(self) -> None:
        for ctx in self._fields.values():
            ctx.close()
        self._fields.clear()

    def run(self, job: Job) -> RunResult:
        """One run; never raises (an exception becomes a failure row)."""
        from segmin.nav_eval.evaluation.rollout import run_episode

        start = time.perf_counter()
        result = RunResult(
            field=field_label(job.field),
            method=job.method,
            run=job.run,
            seed=job.seed,
            model=self.model,
            success=False,
            reason="error",
        )
        try:
            config = self.config if job.config is None else from_dict(NavEvalConfig, job.config)
            ctx = self.field(job.field, config)
            result.depth_threshold = config.depth_threshold(ctx.spec.name, ctx.spec.family)
            simulator = make_simulator(ctx, config)
            result.gap = simulator.gap
            segmenter = with_dropout(with_closing(self.segmenter, config.perception), config.perception, job.seed)
            follower = make_follower(job.method, result.depth_threshold, config)
            with _recorder(job, self.model, config, ctx, result.depth_threshold) as recorder:
                episode = run_episode(
                    simulator, follower, segmenter, job.seed, video=bool(job.video_path), recorder=recorder
                )
            metrics = compute_metrics(
                episode.trajectory,
                simulator.centreline,
                success=episode.success,
                clearance_time=episode.clearance_time,
                collisions=episode.collisions,
            )
            for key in METRIC_KEYS:
                setattr(result, key, metrics[key])
            for key, value in fault_metrics(config.faults, episode.trajectory, episode.driving).items():
                setattr(result, key, value)
            result.success, result.reason = episode.success, episode.reason
            result.goal_m = episode.goal_m
            result.sim_time = float(episode.trajectory.t[-1])
            result.start_x, result.start_y, result.start_yaw = episode.start_pose
            result.trajectory = episode.trajectory
            result.commands = episode.commands
            result.statistics = follower.navigator.statistics()
            if job.video_path and episode.video:
                from segmin.nav_eval.replay.video import write_video

                write_video(job.video_path, episode.video, fps=config.follower.runtime.command_hz)
        except Exception as exc:  # a failed run is a row, never a crash of the evaluation
            result.success, result.reason = False, "error"
            result.error = f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=6)}"
        result.wall_time = time.perf_counter() - start
        return result


def _recorder(job: Job, model: str, config: NavEvalConfig, ctx: FieldContext, depth_threshold: float) -> Any:
    """The run's bag recorder when the job asks for a bag or a live view (a null context otherwise)."""
    if not job.bag_path and not job.live_port:
        return contextlib.nullcontext()
    from segmin import __version__
    from segmin.nav_eval.sim.bag_recorder import RunRecorder

    rates, follower = config.rates, follower_config(job.method, depth_threshold, config)
    metadata = {
        "version": __version__,
        "field": field_label(job.field),
        "method": job.method,
        "run": job.run,
        "seed": job.seed,
        "model": model,
        "depth_threshold": depth_threshold,
        "camera_hz": rates.camera_hz,
        "segment_hz": follower.runtime.segment_hz,
        "command_hz": follower.runtime.command_hz,
        "fuse_frames": follower.navigator.fuse_frames,
    }
    return RunRecorder(job.bag_path or None, ctx.camera, job.seed, metadata, live_port=job.live_port)


# ---------------------------------------------------------------------------------------------
# The matrix
# ---------------------------------------------------------------------------------------------


def run_evaluation(
    model: str | Path,
    fields: str | list[str] = "all",
    methods: str | list[str] = METHODS,
    runs: int = 3,
    out_dir: str | Path | None = None,
    workers: int = 1,
    config: NavEvalConfig | None = None,
    *,
    seed: int = 0,
    video: bool = False,
    bag: bool = False,
    progress: bool = True,
    plots: bool = True,
    executor: Executor = LOCAL,
    resume: bool = False,
    live_port: int = 0,
) -> list[RunResult]:
    """Evaluate `model` ('oracle', an .onnx path or a shipped model name) on fields x methods x runs.

    With `out_dir`, writes results.csv/json (rewritten atomically after every finished run),
    trajectories.json, report.md and the figures, and keeps every finished run in out/runs
    (`run_store`). `resume` (with `out_dir`): an earlier call of this same evaluation that was stopped keeps its
    finished runs and only the missing ones are done (as `segmin robustness` resumes); an
    `out_dir` holding another evaluation's results is refused. Without it every run is done.
    workers <= 1 runs in this process; more uses spawned processes, or `executor`'s (Ray actors)
    whatever the number. `video` / `bag`: run 0 of
    each field and method as a video in out/videos, as a rosbag2 (MCAP) in out/bags. `live_port`:
    stream the one run (one field, method and run, done again even if stored) to a live view.
    Reads top to bottom as plan -> resume -> run (in process or in workers) -> write; kept as one
    function so the resume rules and the rewrite after every run stay side by side.
    """
    config = config or load_nav_config()
    if str(model) != "oracle":
        model = str(resolve_model(model))
    field_list = resolve_fields(fields)
    method_list = parse_methods(methods)
    if runs < 1:
        raise ValueError(f"--runs must be >= 1, got {runs}")
    preflight(str(model), field_list, method_list, config)
    out = check_output_dir(out_dir, "--out") if out_dir is not None else None
    if live_port and len(field_list) * len(method_list) * runs != 1:
        raise ValueError(
            f"--live streams one run: give one field, one method and --runs 1 "
            f"(got {len(field_list)} field(s), {len(method_list)} method(s), {runs} run(s))"
        )
    jobs = []
    for f in field_list:
        for r in range(runs):
            for m in method_list:
                path = bag_path = ""
                if video and out is not None and r == 0:
                    path = str(out / "videos" / f"{field_label(f)}_{m}.mp4")
                if bag and out is not None and r == 0:
                    bag_path = str(out / "bags" / f"{field_label(f)}_{m}")
                jobs.append(Job(f, m, r, run_seed(seed, f, r), path, bag_path, live_port))
    meta = {
        "model": str(model),
        "model_sha256": model_sha256(str(model)),  # what the runs were of (a path may get a new file)
        "fields": [field_label(f) for f in field_list],
        "methods": method_list,
        "runs": runs,
        "seed": seed,
        "workers": workers,
        "config": to_dict(config),
    }
    keys = _run_keys(jobs, str(model), meta["config"]) if out is not None else {}
    finished: dict[str, RunResult] = {}
    if out is not None and resume:
        _say_if_the_model_changed(out, _check_same_evaluation(out, meta), meta)
        finished = stored_runs(out / RUNS_FOLDER, keys.values(), RunResult.from_stored)
    elif out is not None:  # starting over: a later resume must not pick up runs from before
        shutil.rmtree(out / RUNS_FOLDER, ignore_errors=True)
    todo = [job for job in jobs if job.live_port or keys.get(id(job)) not in finished]
    _check_bag_paths(todo)
    if finished:
        log.info("%s: resuming, %d of %d runs finished before, %d to do", out, len(finished), len(jobs), len(todo))
    results: list[RunResult] = list(finished.values())

    def done(job: Job, result: RunResult) -> None:
        results.append(result)
        if out is not None:
            from segmin.nav_eval.evaluation.report import write_results

            if result.reason != "error":  # a run that raised is done again by the next call
                store_run(out / RUNS_FOLDER, keys[id(job)], result, trajectory=True)
            write_results(out, sorted(results, key=_order(jobs)), meta)

    execute_jobs(todo, str(model), config, workers, done, progress=progress, executor=executor)
    results.sort(key=_order(jobs))
    if out is not None:
        from segmin.nav_eval.evaluation.report import write_report

        write_report(out, results, meta, field_list, config, plots=plots)
    return results


def _run_keys(jobs: list[Job], model: str, config: dict[str, Any]) -> dict[int, str]:
    """Each job's key in the run store (by `id(job)`): a hash of what its run depends on, the
    world's content and the model file's included (an edited world or model is run again)."""
    from segmin.data.synth.spec import load_world_spec

    model_id = model_identity(model)
    worlds = {job.field: to_dict(load_world_spec(job.field)) for job in jobs}
    return {
        id(job): digest(
            {
                "world": worlds[job.field],
                "model": model_id,
                "config": config,
                "method": job.method,
                "seed": job.seed,
                "video": bool(job.video_path),
                "bag": bool(job.bag_path),
            }
        )
        for job in jobs
    }


# What may differ in a resumed evaluation: the worker count, and the model's file at the same
# path (its runs are keyed by the content, so those of the old file are redone, said once).
RESUMABLE_META = ("workers", "model_sha256")


def _check_same_evaluation(out: Path, meta: dict[str, Any]) -> dict[str, Any] | None:
    """`out` holds no nav-eval results (None), or this same evaluation's (stopped part-way,
    resumed: its results.json returned); another evaluation's results are not overwritten without --force."""
    from segmin.nav_eval.evaluation.report import RESULT_FILES

    existing = [name for name in RESULT_FILES if (out / name).exists()]
    if not existing:
        return None
    try:
        earlier = json.loads((out / "results.json").read_text())
    except (OSError, ValueError):
        earlier = None
    if not isinstance(earlier, dict):
        why = "no readable results.json to resume from"
    else:
        differs = [k for k in meta if k not in RESUMABLE_META and _plain(earlier.get(k)) != _plain(meta[k])]
        if not differs:
            return earlier
        why = f"another evaluation: its {differs[0]} differs"
    raise ValueError(
        f"{out}: already holds nav-eval results ({', '.join(existing)}; {why}); use --force to overwrite them"
    )


def _say_if_the_model_changed(out: Path, earlier: dict[str, Any] | None, meta: dict[str, Any]) -> None:
    """One log line when the model's file at the same path is not the one of the runs kept in
    `out` (its sha256 differs): why every kept run is done again."""
    before = None if earlier is None else earlier.get("model_sha256")
    if before is None or before == meta["model_sha256"]:
        return
    rows = earlier.get("rows", []) if earlier is not None else []
    log.info(
        "%s: model %s changed since the kept runs (sha256 %s..., now %s...): the %d finished run(s) of the old file "
        "are redone",
        out,
        meta["model"],
        str(before)[:12],
        str(meta["model_sha256"])[:12],
        len(rows) if isinstance(rows, list) else 0,
    )


def _plain(value: Any) -> str:
    """`value` as results.json holds it (tuples as lists, NaN as NaN), to compare with what was read back."""
    return json.dumps(value, sort_keys=True, default=str)


def _check_bag_paths(jobs: list[Job]) -> None:
    """What is in the way of a bag is named before the first run, not after every run."""
    bags = [Path(job.bag_path) for job in jobs if job.bag_path]
    if bags:
        from segmin.nav_eval.sim.bag_recorder import check_bag_path

        for path in bags:
            check_bag_path(path)


def execute_jobs(
    jobs: list[Job],
    model: str,
    config: NavEvalConfig,
    workers: int,
    done: Callable[[Job, RunResult], None],
    *,
    progress: bool = True,
    desc: str = "nav-eval runs",
    executor: Executor = LOCAL,
) -> None:
    """Run `jobs` on `workers` processes (this one when <= 1) or Ray actors (`executor`), calling
    `done(job, result)` as each finishes (in completion order). A job's own `config` replaces
    `config` for that run."""
    bar = _progress(len(jobs), progress, desc)
    try:
        if workers <= 1 and executor.kind == "local":
            # One core is left to pybullet: the episode renders the next frame on this thread
            # while the segmenter runs on its helper thread (see nav_eval.sim).
            worker = Worker(model, config, threads=max(1, (os.cpu_count() or 1) - 1))
            try:
                for job in jobs:
                    done(job, worker.run(job))
                    bar.update(1)
            finally:
                worker.close()
        else:
            _run_pool(jobs, model, config, workers, done, bar, executor)
    finally:
        bar.close()


def _order(jobs: list[Job]) -> Callable[[RunResult], int]:
    index = {(field_label(j.field), j.method, j.run): i for i, j in enumerate(jobs)}
    return lambda r: index.get((r.field, r.method, r.run), len(index))


def _run_pool(
    jobs: list[Job],
    model: str,
    config: NavEvalConfig,
    workers: int,
    done: Callable[[Job, RunResult], None],
    bar: Any,
    executor: Executor,
) -> None:
    """`jobs` on `workers` processes (or Ray actors), each with its own `Worker` (fields and
    segmenter kept between its runs) sharing the cores."""
    threads = max(1, (os.cpu_count() or 1) // workers)

    def finished(job: Job, result: RunResult) -> None:
        done(job, result)
        bar.update(1)

    def failed(job: Job, why: str) -> RunResult:  # its process died: a failure row
        return RunResult(
            field=field_label(job.field),
            method=job.method,
            run=job.run,
            seed=job.seed,
            model=model,
            success=False,
            reason="error",
            error=why,
        )

    make_worker = functools.partial(Worker.from_plain, model, to_dict(config), threads)
    executor.run(jobs, make_worker, workers, finished, failed)


def _progress(total: int, enabled: bool, desc: str) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="run", disable=not enabled)
