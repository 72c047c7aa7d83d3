"""Robustness sweeps, the run: every variant x method x seeded run, resumable, then the tables and plots.

`run_sweep(spec, out)` plans and validates the sweep (`nav_eval.sweep_spec`), writes each world
variant to `out/worlds/`, and runs the jobs on `nav_eval.evaluate`'s runner (the same workers as
nav-eval; a job carries its variant's nav config). Each finished run is kept in
`out/runs/<key>.json` (`nav_eval.evaluation.run_store`, as nav-eval keeps its own), the key a
hash of everything the run depends on (world, nav config, model file content, method, seed): an
interrupted sweep resumes where it stopped and a changed spec reruns only what changed.
Variants that come out equal (a parameter's value that is the base's) share their runs. Runs
that raised are not stored: they are reported and rerun next time.

Seeds: run k uses the same seed for every variant and method (paired: the same start noise
across the values of a parameter), from the base field's name and the spec's seed.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from segmin.common.executor import LOCAL, Executor
from segmin.common.lock import writer_lock
from segmin.nav_eval.evaluation.evaluate import run_seed
from segmin.nav_eval.evaluation.records import Job, RunResult
from segmin.nav_eval.sweeps.keyed_runs import prepare_runs, run_key, run_keyed_jobs, with_command_line, write_world
from segmin.nav_eval.sweeps.report import summarise_sweep, write_sweep_outputs
from segmin.nav_eval.sweeps.spec import SweepPlan, Variant, load_sweep, plan_sweep, variant_file_name


@dataclasses.dataclass
class SweepOutcome:
    """What a sweep call did: the summary rows, and how many runs it executed or reused."""

    plan: SweepPlan
    rows: list[dict[str, Any]]
    executed: int
    reused: int
    errored: list[RunResult]


def run_sweep(
    spec_path: str | Path,
    out_dir: str | Path,
    *,
    model: str | None = None,
    runs: int | None = None,
    workers: int = 1,
    overrides: list[str] | tuple[str, ...] = (),
    force: bool = False,
    progress: bool = True,
    plots: bool = True,
    executor: Executor = LOCAL,
) -> SweepOutcome:
    """Run (or resume) the sweep `spec_path` into `out_dir`; `model` and `runs` replace the spec's."""
    spec, path = load_sweep(spec_path)
    spec = with_command_line(spec, model, runs)
    plan = plan_sweep(spec, str(path), overrides)
    out, model_id = prepare_runs(spec.model, workers, out_dir)
    with writer_lock(out / ".sweep.lock", f"sweep {out}"):
        jobs, keys = _jobs(plan, out, model_id)
        ran = run_keyed_jobs(
            out,
            jobs,
            spec.model,
            plan.base_config,
            workers,
            force=force,
            progress=progress,
            desc="sweep runs",
            executor=executor,
        )
        rows = summarise_sweep(plan, keys, ran.results)
        write_sweep_outputs(
            out, plan, rows, plots=plots, executed=ran.executed, reused=ran.reused, errored=len(ran.errored)
        )
    return SweepOutcome(plan, rows, ran.executed, ran.reused, ran.errored)


def _jobs(plan: SweepPlan, out: Path, model_id: str) -> tuple[dict[str, Job], list[list[tuple[str, str]]]]:
    """One job per distinct (setting, method, seed), keyed by its hash; and each variant's
    (method, key) pairs, in the order of `plan.variants`."""
    spec = plan.spec
    jobs: dict[str, Job] = {}
    keys: list[list[tuple[str, str]]] = []
    written: set[str] = set()
    for variant in plan.variants:
        field = _field(plan, variant, out, written)
        keys.append([])
        for run in range(spec.runs):
            seed = run_seed(spec.seed, plan.base_label, run)
            for method in spec.methods:
                key = run_key(variant.world, variant.config, model_id, method, seed)
                keys[-1].append((method, key))
                if key not in jobs:
                    jobs[key] = Job(field, method, run, seed, config=variant.config)
    return jobs, keys


def _field(plan: SweepPlan, variant: Variant, out: Path, written: set[str]) -> str:
    """The base field itself when the variant's world is the base's, else its written spec file."""
    if variant.world == plan.base_world:
        return plan.spec.base
    path = out / "worlds" / variant_file_name(plan.base_label, variant)
    if str(path) not in written:
        write_world(path, variant.world, f"{plan.where}: {plan.base_label} with {variant.parameter} = {variant.label}")
        written.add(str(path))
    return str(path)
