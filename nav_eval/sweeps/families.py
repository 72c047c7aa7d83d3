"""Families of worlds, the run: every world x setting x method x seeded run, resumable, then the tables.

`run_families(spec, out)` plans and validates the comparison (`family_spec`), writes each world
that is not the shipped recipe to `out/worlds/`, and runs the jobs through the run store the
robustness sweeps use (`keyed_runs`): a killed comparison resumes, a setting added to the spec
runs only its own jobs. Seeds: run k in a world uses the same seed for every setting and method
(paired), from the spec's seed and the world's label; the recipe's own world keeps nav-eval's
seeds, so its run k is nav-eval's run k with the same config.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from segmin.common.executor import LOCAL, Executor
from segmin.common.lock import writer_lock
from segmin.nav_eval.evaluation.evaluate import run_seed
from segmin.nav_eval.evaluation.records import Job, RunResult
from segmin.nav_eval.sim.factories import field_label
from segmin.nav_eval.sweeps.family_report import FamilyRun, Verdict, judge, summarise_families, write_family_outputs
from segmin.nav_eval.sweeps.family_spec import FamilyPlan, load_family_spec, plan_families
from segmin.nav_eval.sweeps.keyed_runs import prepare_runs, run_key, run_keyed_jobs, with_command_line, write_world


@dataclasses.dataclass
class FamilyOutcome:
    """What a family comparison call did: the family rows, the verdicts, and the runs it did."""

    plan: FamilyPlan
    rows: list[dict[str, Any]]
    verdicts: dict[tuple[str, str], Verdict]
    executed: int
    reused: int
    errored: list[RunResult]


def run_families(
    spec_path: str | Path,
    out_dir: str | Path,
    *,
    model: str | None = None,
    runs: int | None = None,
    workers: int = 1,
    overrides: list[str] | tuple[str, ...] = (),
    force: bool = False,
    progress: bool = True,
    executor: Executor = LOCAL,
) -> FamilyOutcome:
    """Run (or resume) the family comparison `spec_path` into `out_dir`; `model` and `runs`
    replace the spec's."""
    spec, path = load_family_spec(spec_path)
    spec = with_command_line(spec, model, runs)
    plan = plan_families(spec, str(path), overrides)
    out, model_id = prepare_runs(spec.model, workers, out_dir)
    with writer_lock(out / ".sweep.lock", f"families {out}"):
        jobs, placed = _jobs(plan, out, model_id)
        ran = run_keyed_jobs(
            out,
            jobs,
            spec.model,
            plan.base_config,
            workers,
            force=force,
            progress=progress,
            desc="family runs",
            executor=executor,
        )
        family_runs = [
            FamilyRun(setting, family, world_seed, ran.results[key])
            for key, setting, family, world_seed in placed
            if key in ran.results
        ]
        rows = summarise_families(family_runs, {name: s.robot for name, s in spec.settings.items()})
        verdicts = judge(rows, spec.paper_method, field_label(spec.flat_reference), spec.sloped_within)
        write_family_outputs(out, plan, rows, verdicts, ran)
    return FamilyOutcome(plan, rows, verdicts, ran.executed, ran.reused, ran.errored)


def _jobs(plan: FamilyPlan, out: Path, model_id: str) -> tuple[dict[str, Job], list[tuple[str, str, str, int]]]:
    """One job per (world, setting, method, run), keyed by its hash; and each job's place
    (key, setting, family, world seed), in table order."""
    spec = plan.spec
    jobs: dict[str, Job] = {}
    placed: list[tuple[str, str, str, int]] = []
    for member in plan.members:
        field = member.field
        if not member.shipped:
            header = f"{plan.where}: {member.family} with world seed {member.world_seed}"
            field = write_world(out / "worlds" / member.field, member.world, header)
        for setting, config in plan.configs.items():
            for run in range(spec.runs):
                seed = run_seed(spec.seed, member.label, run)
                for method in spec.methods:
                    key = run_key(member.world, config, model_id, method, seed)
                    jobs[key] = Job(field, method, run, seed, config=config)
                    placed.append((key, setting, member.family, member.world_seed))
    return jobs, placed
