"""`segmin pipeline`: render -> train -> export -> nav-eval -> report, cached and resumable."""

from __future__ import annotations

import argparse
import sys

from segmin.app.pipeline.config import STAGES
from segmin.common.cli_args import add_overrides, overrides_of
from segmin.common.shipped import shipped_names


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "pipeline",
        help="render worlds, train per crop family, export ONNX, drive the test fields, write a report",
        description="Runs every stage in order. Each stage records the hash of its inputs: a rerun skips "
        "stages whose inputs did not change and resumes an interrupted one. The last line printed names "
        "the report.",
    )
    parser.add_argument(
        "--config",
        default="quick",
        help=f"profile name in configs/pipeline/ ({', '.join(shipped_names('pipeline'))}) or a YAML path "
        "(default: quick)",
    )
    parser.add_argument("--out", default=None, help="run folder (default: runs/<profile>)")
    parser.add_argument(
        "--from",
        dest="from_stage",
        choices=STAGES,
        default=None,
        help="rerun this stage and every later one from scratch",
    )
    add_overrides(parser, alias=False, example="render.frames_per_world=100 nav.runs=3")
    parser.set_defaults(func=_pipeline)


def _pipeline(args: argparse.Namespace) -> int:
    import shlex
    from pathlib import Path

    from segmin.app.pipeline.config import load_pipeline_config
    from segmin.app.pipeline.runner import PipelineRunner
    from segmin.nav_eval.evaluation.evaluate import RunErrors

    config = load_pipeline_config(args.config, overrides_of(args))
    out = Path(args.out) if args.out else Path("runs") / config.profile
    command = shlex.join(
        [
            "segmin",
            "pipeline",
            "--config",
            args.config,
            "--out",
            str(out),
            *(["--from", args.from_stage] if args.from_stage else []),
            *overrides_of(args),
        ]
    )
    try:
        report = PipelineRunner(config, out, from_stage=args.from_stage, command=command).run()
    except RunErrors as exc:  # the stage stays unfinished; a rerun does it again
        print(f"segmin: error: {exc}", file=sys.stderr)
        return 1
    if config.release:
        print(f"released: {out / 'release'} (models, cards and contact sheets as `segmin models release` ships them)")
    print(f"report: {report} (and {report.with_suffix('.html')})")
    return 0
