"""`segmin robustness`: parameter sweeps of the closed-loop evaluation."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from segmin.common.cli_args import add_executor_options, add_overrides, executor_of, overrides_of


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    sweep = commands.add_parser(
        "robustness",
        help="sweep one field's parameters (curve radius, row spacing, noise, ...): where each method breaks",
        description="Run every method on variants of one field, one parameter changed at a time through the "
        "values of a sweep spec (configs/sweeps/*.yaml or your own), with seeded runs. Resumable: finished runs "
        "are stored under OUT/runs and not redone (--force redoes them). Writes sweep.csv, summary.md, "
        "sweep_<parameter>.png (success rate and MAE against the value) and envelope.png (both, for every "
        "parameter). The robot is the skid-steer one unless the spec says 'robot: kinematic'. A spec with "
        "'families:' instead compares settings on families of worlds (each field recipe with several world "
        "seeds) and writes families.csv and summary.md: each family's mean MAE with its 95 % interval beside "
        "the paper's figure, which settings meet the targets, and the choice per robot.",
    )
    sweep.add_argument("spec", help="a shipped sweep (vineyards, trees, families) or a sweep spec YAML")
    sweep.add_argument("--out", type=Path, required=True, help="output folder (reused to resume)")
    sweep.add_argument(
        "--model", default=None, help="replaces the spec's model: an .onnx file, a shipped model name or 'oracle'"
    )
    sweep.add_argument("--runs", type=int, default=None, help="replaces the spec's runs per value and method")
    sweep.add_argument("--workers", type=int, default=1, help="parallel worker processes (default 1)")
    add_executor_options(sweep)
    sweep.add_argument("--force", action="store_true", help="redo the runs stored under OUT/runs")
    sweep.add_argument("--no-plots", action="store_true", help="skip the figures")
    sweep.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_overrides(sweep, example="run.length_m=5 (nav config, after the spec's own overrides)")
    sweep.set_defaults(func=_robustness)


def _robustness(args: argparse.Namespace) -> int:
    from segmin.nav_eval.sweeps.family_spec import is_family_spec
    from segmin.nav_eval.sweeps.report import breaks
    from segmin.nav_eval.sweeps.run import run_sweep

    if is_family_spec(args.spec):
        return _families(args)
    outcome = run_sweep(args.spec, args.out, plots=not args.no_plots, **_run_options(args))
    methods = outcome.plan.spec.methods
    print("| parameter | " + " | ".join(methods) + " |\n" + "|---" * (1 + len(methods)) + "|")
    for name, per_method in breaks(outcome.plan, outcome.rows).items():
        print(f"| {name} | " + " | ".join(per_method[m] for m in methods) + " |")
    print(f"runs: {outcome.executed} executed, {outcome.reused} reused; outputs: {args.out}/summary.md, sweep.csv")
    return _errored(outcome.errored)


def _families(args: argparse.Namespace) -> int:
    from segmin.nav_eval.sweeps.families import run_families
    from segmin.nav_eval.sweeps.family_report import choose

    outcome = run_families(args.spec, args.out, **_run_options(args))
    for method in outcome.plan.spec.methods:
        for robot, setting in choose(outcome.rows, outcome.verdicts, method).items():
            print(f"{method}, {robot}: {setting or 'no setting meets every target'}")
    print(f"runs: {outcome.executed} executed, {outcome.reused} reused; outputs: {args.out}/summary.md, families.csv")
    return _errored(outcome.errored)


def _run_options(args: argparse.Namespace) -> dict[str, Any]:
    """The options both kinds of sweep take from the command line."""
    return {
        "model": args.model,
        "runs": args.runs,
        "workers": args.workers,
        "overrides": overrides_of(args),
        "force": args.force,
        "progress": not args.no_progress,
        "executor": executor_of(args),
    }


def _errored(errored: list) -> int:
    """Name the runs that raised (they are not in the tables and run again next time): exit 1."""
    for r in errored:
        print(f"run raised: {r.field}/{r.method}/{r.run}: {r.error.splitlines()[0]}")
    if errored:
        print(
            f"segmin: error: {len(errored)} run(s) raised; they are not in the tables and run again next time",
            file=sys.stderr,
        )
        return 1
    return 0
