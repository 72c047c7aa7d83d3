"""`segmin nav-eval`: closed-loop evaluation in the simulated test fields."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from segmin.common.cli_args import add_executor_options, add_overrides, executor_of, overrides_of
from segmin.nav_eval.live.options import add_live_options, live_port
from segmin.nav_eval.runtime.methods import METHODS


def add_scenario_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config", type=Path, default=None, help="evaluation config YAML (default: configs/nav/default.yaml)"
    )
    add_overrides(parser, example="run.length_m=10")
    parser.add_argument("--seed", type=int, default=0, help="base seed of the start noise (default 0)")


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "nav-eval",
        help="closed-loop navigation in the simulated test fields (Table 3 metrics, plots)",
        description="Drive a simulated Jackal through the row gaps of the test fields with the paper's SegMin, "
        "SegMinD and SegZeros and/or SegCorridor (the corridor follower), guided by an exported ONNX model or the simulator's exact mask ('oracle'). Writes "
        "results.csv, results.json, report.md, trajectory and histogram figures (and MP4 videos with --video). "
        "Resumable: finished runs are kept under OUT/runs, and the same call again does only the missing ones "
        "(--force redoes them all).",
    )
    parser.add_argument(
        "--model",
        required=True,
        help="exported .onnx or .tflite file, a shipped model name (vineyards, trees), or 'oracle' (exact masks)",
    )
    parser.add_argument(
        "--fields", default="all", help="'all' (the five test fields), comma-separated names, or world spec YAML paths"
    )
    parser.add_argument(
        "--methods", default=",".join(METHODS), help=f"comma-separated methods (default all: {','.join(METHODS)})"
    )
    parser.add_argument("--runs", type=int, default=3, help="runs per field and method (default 3)")
    parser.add_argument(
        "--out",
        type=Path,
        required=True,
        help="output folder (reused to resume the same evaluation; refused if it holds another's results, unless --force)",
    )
    parser.add_argument(
        "--force", action="store_true", help="start over: redo every run and overwrite the results in --out"
    )
    parser.add_argument("--workers", type=int, default=1, help="parallel worker processes (default 1)")
    add_executor_options(parser)
    parser.add_argument(
        "--video",
        action="store_true",
        help="MP4 (else GIF) of the camera view, mask and chosen column for run 0 of each field and method",
    )
    parser.add_argument(
        "--bag",
        action="store_true",
        help="rosbag2 (MCAP) of run 0 of each field and method in OUT/bags/: camera, depth, IMU, odometry, "
        "ground truth, cmd_vel, TF (needs the [ros] extra; replay it with segmin replay --bag)",
    )
    add_live_options(parser, rate=False)
    parser.add_argument("--no-plots", action="store_true", help="skip the figures")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_scenario_options(parser)
    parser.set_defaults(func=_nav_eval)


def _nav_eval(args: argparse.Namespace) -> int:
    from segmin.nav_eval.evaluation.evaluate import run_evaluation
    from segmin.nav_eval.evaluation.report import table3_markdown
    from segmin.nav_eval.sim.config import load_nav_config

    config = load_nav_config(args.config, overrides_of(args))
    if args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    if args.live and args.executor == "ray":  # the run's server would listen on a Ray worker's loopback
        raise ValueError("--live streams a run from this computer: leave out --executor ray")
    executor = executor_of(args)
    if args.bag:
        import rosbags.rosbag2  # noqa: F401  (a missing [ros] extra is named now, not in every run)
    port = live_port(args)  # a taken port or a missing [live] extra is said before the run
    results = run_evaluation(
        args.model,
        args.fields,
        args.methods,
        args.runs,
        args.out,
        args.workers,
        config,
        seed=args.seed,
        video=args.video,
        bag=args.bag,
        progress=not args.no_progress,
        plots=not args.no_plots,
        executor=executor,
        resume=not args.force,
        live_port=port,
    )
    print(table3_markdown(results), end="")
    failed = [r for r in results if r.reason == "error"]
    for r in failed:
        print(f"run raised: {r.field}/{r.method}/{r.run}: {r.error.splitlines()[0]}")
    print(f"outputs: {args.out}/report.md, results.csv, results.json")
    if failed:  # runs that raised are errors, not results: the evaluation did not succeed
        print(
            f"segmin: error: {len(failed)} of {len(results)} run(s) raised (see above and "
            f"{args.out}/results.csv); the table is incomplete",
            file=sys.stderr,
        )
        return 1
    return 0
