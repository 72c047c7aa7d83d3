"""`segmin train` and `segmin bench train`; also `torchrun --nproc-per-node N -m segmin.train.cli ...`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from segmin.common.cli_args import CommandParser, add_overrides, overrides_of
from segmin.common.console_log import show_progress


def _add_train_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="configs/train/<family>.yaml")
    add_overrides(parser, alias=False, example="epochs=5 data.root=/data/agriseg batch_size=16")
    parser.add_argument("--out", default=None, help="run folder (default runs/train/<config name>)")
    parser.add_argument("--resume", action="store_true", help="continue exactly from <out>/last.pt")
    parser.add_argument(
        "--force",
        action="store_true",
        help="start over in an --out that already holds a run (its checkpoints and logs are removed)",
    )


def register(commands, bench) -> None:
    train = commands.add_parser("train", help="train the segmentation network (CPU, one GPU or torchrun)")
    _add_train_arguments(train)
    train.set_defaults(func=_train)

    b = bench.add_parser("train", help="training images/s: full data pipeline vs the model step alone")
    b.add_argument("--root", type=Path, default=None, help="dataset root (default: a generated 320x240 PNG set)")
    b.add_argument("--size", type=int, default=224)
    b.add_argument("--batch", type=int, default=8)
    b.add_argument("--threads", type=int, default=2)
    b.add_argument("--workers", type=int, default=1)
    b.add_argument("--steps", type=int, default=6)
    b.add_argument("--repeats", type=int, default=2)
    b.add_argument("--device", default="cpu")
    b.set_defaults(func=_bench)

    bound = bench.add_parser(
        "iou-bound", help="estimated crop-IoU ceiling that LR-ASPP's 1/8-resolution output puts on a dataset's masks"
    )
    bound.add_argument("--root", required=True, help="dataset root (any layout data.agriseg_loader reads)")
    bound.add_argument("--domains", nargs="+", default=None, help="domains or families (default: all)")
    bound.add_argument(
        "--sizes", type=int, nargs="+", default=[128, 192, 224], help="input sides (default 128 192 224)"
    )
    bound.add_argument("--frames", type=int, default=200, help="masks to use, evenly spaced (default 200)")
    bound.add_argument("--steps", type=int, default=150, help="Adam steps of the logit fit (default 150)")
    bound.set_defaults(func=_bench_iou_bound)


def _train(args: argparse.Namespace) -> int:
    from segmin.train.config import load_train_config
    from segmin.train.run import fit

    config = load_train_config(args.config, overrides_of(args))
    out = Path(args.out) if args.out else Path("runs/train") / Path(args.config).stem
    result = fit(config, out, resume=args.resume, force=args.force)
    if result.interrupted:
        return 130
    if result.rank == 0:
        best = result.history and max(r["val_iou"] for r in result.history)
        kept = f"; the weight average {result.swa_path}" if result.swa_path else ""
        print(f"done: best val IoU {best:.4f}; best checkpoint {result.best_path}{kept}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from segmin.train.bench import TrainBenchOptions, bench_train, report_lines

    options = TrainBenchOptions(
        root=args.root,
        image_size=args.size,
        batch_size=args.batch,
        threads=args.threads,
        steps=args.steps,
        workers=args.workers,
        repeats=args.repeats,
        device=args.device,
    )
    print("\n".join(report_lines(bench_train(options))))
    return 0


def _bench_iou_bound(args: argparse.Namespace) -> int:
    from segmin.train.resolution_bound import check_size, iou_bound, load_masks, resize_masks

    if args.steps < 0:
        raise ValueError(f"--steps {args.steps}: must be >= 0")
    for size in args.sizes:
        check_size(size)
    masks = load_masks(args.root, args.domains, args.frames)
    print(
        f"IoU ceilings of LR-ASPP (logits at 1/8 resolution, bilinear upsampling) on {args.root}"
        f" {args.domains or '(all domains)'}"
    )
    print(f"{'input':>7}{'logit grid':>12}{'frames':>8}{'area-average':>14}{'fitted logits':>15}")
    for size in args.sizes:
        b = iou_bound(resize_masks(masks, size), steps=args.steps)
        print(f"{b.size:>7}{f'{b.grid}x{b.grid}':>12}{b.frames:>8}{b.area_iou:>14.3f}{b.fitted_iou:>15.3f}")
    print(
        "fitted is a close estimate of the ceiling from below (BCE fit of the logit grid);"
        " a target well above it is out of reach at that input size"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry for `python -m segmin.train.cli` (what torchrun launches): the same arguments as `segmin train`."""
    parser = CommandParser(prog="segmin.train.cli", description="segmin training (torchrun entry)")
    _add_train_arguments(parser)
    args = parser.parse_args(argv)
    show_progress()
    return _train(args)


if __name__ == "__main__":
    sys.exit(main())
