"""`segmin nav-eval` (closed-loop evaluation), `segmin robustness` (parameter sweeps of it) and
`segmin bench nav-eval` (simulation speed)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from segmin.common.cli_args import add_overrides, overrides_of
from segmin.nav_eval.methods import METHODS


def _add_common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, default=None,
                        help="evaluation config YAML (default: configs/nav/default.yaml)")
    add_overrides(parser, example="run.length_m=10")
    parser.add_argument("--seed", type=int, default=0, help="base seed of the start noise (default 0)")


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "nav-eval",
        help="closed-loop navigation in the simulated test fields (Table 3 metrics, plots)",
        description="Drive a simulated Jackal through the row gaps of the test fields with SegMin, SegMinD "
        "and/or SegZeros, guided by an exported ONNX model or the simulator's exact mask ('oracle'). Writes "
        "results.csv, results.json, report.md, trajectory and histogram figures (and MP4 videos with --video).",
    )
    parser.add_argument("--model", required=True, help="exported .onnx file, or 'oracle' (exact masks)")
    parser.add_argument("--fields", default="all",
                        help="'all' (the five test fields), comma-separated names, or world spec YAML paths")
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods")
    parser.add_argument("--runs", type=int, default=3, help="runs per field and method (default 3)")
    parser.add_argument("--out", type=Path, required=True, help="output folder (refused if it holds results, unless --force)")
    parser.add_argument("--force", action="store_true", help="overwrite the results of an earlier nav-eval in --out")
    parser.add_argument("--workers", type=int, default=1, help="parallel worker processes (default 1)")
    parser.add_argument("--video", action="store_true", help="MP4 (else GIF) of the camera view, mask and chosen column for run 0 of each field and method")
    parser.add_argument("--no-plots", action="store_true", help="skip the figures")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_common(parser)
    parser.set_defaults(func=_nav_eval)

    sweep = commands.add_parser(
        "robustness",
        help="sweep one field's parameters (curve radius, row spacing, noise, ...): where each method breaks",
        description="Run every method on variants of one field, one parameter changed at a time through the "
        "values of a sweep spec (configs/sweeps/*.yaml or your own), with seeded runs. Resumable: finished runs "
        "are stored under OUT/runs and not redone (--force redoes them). Writes sweep.csv, summary.md, "
        "sweep_<parameter>.png (success rate and MAE against the value) and envelope.png.",
    )
    sweep.add_argument("spec", help="a shipped sweep (vineyards, trees) or a sweep spec YAML")
    sweep.add_argument("--out", type=Path, required=True, help="output folder (reused to resume)")
    sweep.add_argument("--model", default=None, help="replaces the spec's model: an .onnx file or 'oracle'")
    sweep.add_argument("--runs", type=int, default=None, help="replaces the spec's runs per value and method")
    sweep.add_argument("--workers", type=int, default=1, help="parallel worker processes (default 1)")
    sweep.add_argument("--force", action="store_true", help="redo the runs stored under OUT/runs")
    sweep.add_argument("--no-plots", action="store_true", help="skip the figures")
    sweep.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_overrides(sweep, example="run.length_m=5 (nav config, after the spec's own overrides)")
    sweep.set_defaults(func=_robustness)

    b = bench.add_parser("nav-eval", help="simulated seconds per wall-clock second (one worker, ONNX segmenter)")
    b.add_argument("--model", default=None,
                   help="ONNX file or 'oracle' (default: an untrained model exported to a temporary file)")
    b.add_argument("--field", default="straight_vineyard", help="field to drive (default straight_vineyard)")
    b.add_argument("--method", default="segmind", help="navigator method (default segmind)")
    b.add_argument("--seconds", type=float, default=20.0, help="simulated seconds to drive (default 20)")
    b.add_argument("--threads", type=int, default=1, help="onnxruntime threads (default 1, as with 2 workers)")
    b.add_argument("--matrix", action="store_true",
                   help="also run the full matrix (5 fields x 3 methods x 3 runs) on --workers and time it")
    b.add_argument("--workers", type=int, default=2, help="workers for --matrix (default 2)")
    b.add_argument("--out", type=Path, default=None, help="folder for --matrix outputs (default: a temp folder)")
    _add_common(b)
    b.set_defaults(func=_bench)


def _nav_eval(args: argparse.Namespace) -> int:
    from segmin.common.outputs import check_results_absent
    from segmin.nav_eval.eval_config import load_nav_config
    from segmin.nav_eval.evaluate import run_evaluation
    from segmin.nav_eval.report import RESULT_FILES, table3_markdown

    config = load_nav_config(args.config, overrides_of(args))
    if args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    check_results_absent(args.out, RESULT_FILES, args.force, "nav-eval")
    results = run_evaluation(args.model, args.fields, args.methods, args.runs, args.out, args.workers, config,
                             seed=args.seed, video=args.video, progress=not args.no_progress,
                             plots=not args.no_plots)
    print(table3_markdown(results), end="")
    failed = [r for r in results if r.reason == "error"]
    for r in failed:
        print(f"run raised: {r.field}/{r.method}/{r.run}: {r.error.splitlines()[0]}")
    print(f"outputs: {args.out}/report.md, results.csv, results.json")
    if failed:  # runs that raised are errors, not results: the evaluation did not succeed
        print(f"segmin: error: {len(failed)} of {len(results)} run(s) raised (see above and "
              f"{args.out}/results.csv); the table is incomplete", file=sys.stderr)
        return 1
    return 0


def _robustness(args: argparse.Namespace) -> int:
    from segmin.nav_eval.sweep import run_sweep
    from segmin.nav_eval.sweep_report import breaks

    outcome = run_sweep(args.spec, args.out, model=args.model, runs=args.runs, workers=args.workers,
                        overrides=overrides_of(args), force=args.force, progress=not args.no_progress,
                        plots=not args.no_plots)
    methods = outcome.plan.spec.methods
    print("| parameter | " + " | ".join(methods) + " |\n" + "|---" * (1 + len(methods)) + "|")
    for name, per_method in breaks(outcome.plan, outcome.rows).items():
        print(f"| {name} | " + " | ".join(per_method[m] for m in methods) + " |")
    print(f"runs: {outcome.executed} executed, {outcome.reused} reused; outputs: {args.out}/summary.md, sweep.csv")
    for r in outcome.errored:
        print(f"run raised: {r.field}/{r.method}/{r.run}: {r.error.splitlines()[0]}")
    if outcome.errored:
        print(f"segmin: error: {len(outcome.errored)} run(s) raised; they are not in the tables and run again "
              "next time", file=sys.stderr)
        return 1
    return 0


def _bench(args: argparse.Namespace) -> int:
    from segmin.nav_eval.bench import bench_nav_eval

    bench_nav_eval(args)
    return 0
