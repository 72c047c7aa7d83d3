"""`segmin export` (in the app layer: it also takes a shipped model's name, which the registry in the
robot runtime resolves).

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
        help="checkpoint (best.pt / last.pt), or a segmin fp32 .onnx file or a shipped model's name (vineyards, "
        "trees) to export to another format (converted back to PyTorch first; needs --calib-data)",
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


def _source(checkpoint: str) -> Path:
    """The file `--checkpoint` names: an existing file wins; a shipped model's name is its ONNX file."""
    from segmin.nav_eval.runtime.shipped_models import SHIPPED_NAMES, resolve_model

    path = Path(checkpoint)
    return resolve_model(checkpoint, "--checkpoint") if checkpoint in SHIPPED_NAMES and not path.exists() else path


def run_export(args: argparse.Namespace) -> int:
    from segmin.common.outputs import check_output_file

    check_output_file(args.out, "--out")  # before the (slow) exporter imports
    from segmin.export.pipeline import ExportOptions, export_checkpoint

    options = ExportOptions(
        checkpoint=_source(args.checkpoint),
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
