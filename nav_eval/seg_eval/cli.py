"""`segmin eval-seg`: IoU, precision, recall and steering figures of an ONNX file or checkpoint on labelled photos."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "eval-seg",
        help="score a model (.onnx, .tflite or checkpoint .pt) on labelled photos: IoU, precision, recall, steering, contact sheet",
        description=(
            "Segment every labelled image under --data (any layout the AgriSeg loader reads, e.g. a flat "
            "images/ + masks/ folder) and compare with the masks at their own resolution. Prints mean IoU over "
            "images, and the pooled (all pixels of the set) IoU, precision, recall and pixel accuracy; where each mask would "
            "steer (the SegMin target of the model's mask against the truth's, the truth's free corridor, a drivable "
            "strip when strips/ labels one) and the share of uniform frames painted as crop; writes results.csv, results.json and "
            "contact_sheet.png (photo | errors: green found, red false crop, blue missed | ground truth). "
            "IoU of an image with empty truth and empty prediction is 1.0; precision is n/a on an image where "
            "nothing is predicted, recall where nothing is labelled (the pooled figures stay defined as long as "
            "any image has some)."
        ),
    )
    parser.add_argument(
        "--model",
        required=True,
        type=Path,
        help="exported .onnx or .tflite (size and threshold from its metadata), a shipped model name (vineyards, "
        "trees) or a training checkpoint .pt",
    )
    parser.add_argument(
        "--data",
        type=Path,
        default=None,
        help="labelled photos (default: the shipped real vineyard rows, data/real/vineyard_rows)",
    )
    parser.add_argument("--out", type=Path, default=None, help="results folder (default: runs/eval-seg/<model name>)")
    parser.add_argument("--threshold", type=float, default=None, help="probability threshold (default: the model's)")
    parser.add_argument(
        "--size",
        type=int,
        default=None,
        help="square input size for a checkpoint, a multiple of 32 (default: its training size; an ONNX input is fixed)",
    )
    parser.add_argument(
        "--truth-closing",
        type=int,
        default=0,
        metavar="PX",
        help="score against the canopy region: each mask closed with a disc of PX pixels, as a training "
        "config's data.label_closing builds its labels (default 0: the exact masks)",
    )
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime / torch threads (default 2)")
    parser.add_argument("--force", action="store_true", help="overwrite results already in --out")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=run_eval_seg)


def run_eval_seg(args: argparse.Namespace) -> int:
    from segmin.common.mask_closing import check_closing_radius
    from segmin.data.real_sets import shipped_real_data
    from segmin.nav_eval.runtime.shipped_models import looks_like_name, resolve_model
    from segmin.nav_eval.seg_eval.results import check_out_dir, write_results
    from segmin.nav_eval.seg_eval.score import evaluate_model

    if args.threads < 1:
        raise ValueError(f"--threads {args.threads}: must be >= 1")
    check_closing_radius(args.truth_closing, "--truth-closing")  # before the model loads
    model = resolve_model(args.model) if looks_like_name(args.model) else args.model  # "vineyards": the shipped file
    data = args.data if args.data is not None else shipped_real_data()
    out = args.out if args.out is not None else Path("runs") / "eval-seg" / args.model.stem
    check_out_dir(out, args.force)  # before the model runs: refusing late would waste the work
    if model.suffix.lower() not in (".onnx", ".tflite"):  # a checkpoint: PyTorch runs it
        import torch

        torch.set_num_threads(args.threads)
    summary, sheet = evaluate_model(
        model,
        data,
        threshold=args.threshold,
        size=args.size,
        threads=args.threads,
        truth_closing=args.truth_closing,
        progress=not args.no_progress and sys.stderr.isatty(),
    )
    paths = write_results(summary, sheet, out, force=args.force)
    print("\n".join(summary.summary_lines()))
    print(
        f"results: {paths['csv']}, {paths['json']}"
        + (f"; contact sheet: {paths['contact_sheet']}" if "contact_sheet" in paths else "")
    )
    return 0
