"""`segmin bench export`: export-side latencies plus the robot-side perception + control step.

This glue lives in the application layer because it joins two packages: `export.bench` times
PyTorch eager against the exported onnxruntime graphs, and `nav_eval.bench.runtime` supplies the
full OnnxSegmenter + Navigator step, which export itself must not import (nav_eval is downstream).
"""

from __future__ import annotations

import argparse
from pathlib import Path


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    parser = bench.add_parser(
        "export",
        help="per-frame latency: PyTorch eager vs onnxruntime fp32 / INT8, and one full SegMinD step",
    )
    parser.add_argument("--checkpoint", type=Path, default=None, help="checkpoint (default: random weights)")
    parser.add_argument("--onnx", type=Path, default=None, help="an exported fp32 file to time instead")
    parser.add_argument("--size", type=int, default=224, help="square input size (default 224)")
    parser.add_argument("--threads", type=int, default=2, help="threads for torch and onnxruntime (default 2)")
    parser.add_argument("--runs", type=int, default=200, help="timed frames per model (default 200)")
    parser.add_argument("--no-int8", action="store_true", help="skip building and timing INT8")
    parser.add_argument(
        "--compare-exporters", action="store_true", help="also time the legacy TorchScript exporter's graph"
    )
    parser.add_argument("--calib-data", type=Path, default=None, help="frames for INT8 calibration")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    parser.set_defaults(func=run_bench)


def run_bench(args: argparse.Namespace) -> int:
    from segmin.export.bench import ExportBenchOptions, run_benchmark
    from segmin.nav_eval.bench.runtime import perception_step_candidates

    options = ExportBenchOptions(
        checkpoint=args.checkpoint,
        onnx=args.onnx,
        size=args.size,
        threads=args.threads,
        runs=args.runs,
        int8=not args.no_int8,
        compare_exporters=args.compare_exporters,
        calib_data=args.calib_data,
        json=args.json,
    )
    run_benchmark(options, step_candidates=perception_step_candidates)
    return 0
