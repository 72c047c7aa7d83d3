"""`segmin export` and `segmin bench model-speed`.

The export latency bench (PyTorch eager against onnxruntime) is a developer's: `python -m benchmarks export`.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def register(commands, bench) -> None:
    parser = commands.add_parser(
        "export",
        help="export a checkpoint to a verified ONNX or LiteRT file (uint8 RGB NHWC in, probability out)",
        description=(
            "Export a segmin checkpoint to ONNX (or LiteRT with --format tflite). The graph takes uint8 RGB "
            "frames N x H x W x 3 (LiteRT: 1 x H x W x 3) and returns vegetation probability N x 1 x H x W; it "
            "is verified against PyTorch on real frames (max |dp| <= 1e-4, mask agreement >= 99.9 %) and not "
            "written if it fails."
        ),
    )
    parser.add_argument(
        "--checkpoint",
        required=True,
        type=Path,
        help="checkpoint (best.pt / last.pt), or a segmin fp32 .onnx file to export to another format (needs "
        "--calib-data; for a shipped model: segmin models to-litert)",
    )
    parser.add_argument("--out", required=True, type=Path, help="output file (.onnx, or .tflite with --format tflite)")
    parser.add_argument(
        "--format",
        choices=("onnx", "tflite"),
        default="onnx",
        help="onnx (onnxruntime, TensorRT; default) or tflite (LiteRT with XNNPACK, converted by litert-torch)",
    )
    parser.add_argument(
        "--calib-data",
        type=Path,
        default=None,
        help="folder of real frames (PNG/JPG images or an AgriSeg root) for verification and INT8 "
        "calibration; default: the checkpoint's training data folder",
    )
    parser.add_argument(
        "--fp16", action="store_true", help="also write <out>.fp16.onnx (GPU / Jetson targets; ONNX only)"
    )
    parser.add_argument(
        "--int8",
        action="store_true",
        help="also write <out>.int8.onnx (static QDQ) or <out>.int8.tflite (full integer), calibrated",
    )
    parser.add_argument("--force", action="store_true", help="overwrite existing output files")
    parser.add_argument("--opset", type=int, default=None, help="ONNX opset (default 18 dynamo, 17 legacy)")
    parser.add_argument(
        "--exporter", choices=("dynamo", "legacy"), default=None, help="torch.onnx exporter (default dynamo; ONNX only)"
    )
    parser.add_argument("--verify-frames", type=int, default=32, help="frames compared with PyTorch (default 32)")
    parser.add_argument("--calib-frames", type=int, default=32, help="frames for INT8 calibration (default 32)")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime / LiteRT threads for checks (default 2)")
    parser.set_defaults(func=run_export)
    _register_model_speed(bench)
    _register_litert_speed(bench)


def run_export(args: argparse.Namespace) -> int:
    from segmin.common.outputs import check_output_file

    check_output_file(args.out, "--out")  # before the (slow) exporter imports
    from segmin.export.pipeline import ExportOptions, export_checkpoint

    options = ExportOptions(
        checkpoint=args.checkpoint,
        out=args.out,
        calib_data=args.calib_data,
        fp16=args.fp16,
        int8=args.int8,
        force=args.force,
        opset=args.opset,
        exporter=args.exporter,
        format=args.format,
        verify_frames=args.verify_frames,
        calib_frames=args.calib_frames,
        threads=args.threads,
    )
    report = export_checkpoint(options)
    verification = report["fp32"]["verification_vs_torch"]
    print(
        f"{report['fp32']['path']}: verified on {verification['frames']} frames, "
        f"max |p_{args.format} - p_torch| {verification['max_abs_diff']:.2e}, "
        f"mask agreement {100 * verification['mask_agreement']:.3f} %"
    )
    if "fp16" in report:
        vs = report["fp16"]["vs_fp32"]
        print(f"{report['fp16']['path']}: max |dp| vs fp32 {vs['max_abs_diff']:.2e}, mask IoU {vs['mask_iou']:.4f}")
    if "int8" in report:
        print(f"{report['int8']['path']}: {report['int8']['recommendation']}")
    return 0


def _register_model_speed(bench) -> None:
    from segmin.models.architectures import ARCHITECTURES

    parser = bench.add_parser(
        "model-speed",
        help="onnxruntime frame time of the candidate networks as a ratio to today's full network",
        description=(
            "Export every architecture (random weights) at every size, time them alternately in one "
            "session with onnxruntime, and print median / p95 ms, the ratio to the full network at "
            "224 px, parameters, file size and the optimised graph's op counts, with the load average."
        ),
    )
    parser.add_argument(
        "--architectures",
        nargs="+",
        default=list(ARCHITECTURES),
        metavar="NAME",
        help=f"networks to time (default: all: {', '.join(ARCHITECTURES)}); the full network is always timed",
    )
    parser.add_argument("--sizes", nargs="+", type=int, default=[224, 192], help="square input sizes (default 224 192)")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads (default 2)")
    parser.add_argument("--runs", type=int, default=200, help="timed frames per candidate (default 200)")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    parser.set_defaults(func=run_model_speed)


def run_model_speed(args: argparse.Namespace) -> int:
    from segmin.export.bench_models import ModelSpeedOptions
    from segmin.export.bench_models import run_model_speed as run

    run(
        ModelSpeedOptions(
            architectures=tuple(args.architectures),
            sizes=tuple(args.sizes),
            threads=args.threads,
            runs=args.runs,
            json=args.json,
        )
    )
    return 0


def _register_litert_speed(bench) -> None:
    parser = bench.add_parser(
        "litert-speed",
        help="LiteRT (.tflite) files' frame time side by side, and the ops XNNPACK leaves out of each",
        description=(
            "Time LiteRT files alternately in one process (XNNPACK, per thread count) and print median / p95 "
            "ms, the ratio to the first file and the load average; before that, each file's XNNPACK partitions "
            "and the ops left to LiteRT's own kernels (why an INT8 file can be slower than fp32)."
        ),
    )
    parser.add_argument("--models", nargs="+", required=True, type=Path, metavar="FILE", help=".tflite files")
    parser.add_argument("--threads", nargs="+", type=int, default=[2, 1], help="thread counts (default 2 1)")
    parser.add_argument("--rounds", type=int, default=6, help="alternating rounds (default 6)")
    parser.add_argument("--runs", type=int, default=240, help="timed frames per file and thread count (default 240)")
    parser.set_defaults(func=run_litert_speed)


def run_litert_speed(args: argparse.Namespace) -> int:
    from segmin.export.bench_litert import LiteRtSpeedOptions
    from segmin.export.bench_litert import run_litert_speed as run

    run(LiteRtSpeedOptions(tuple(args.models), tuple(args.threads), args.rounds, args.runs))
    return 0
