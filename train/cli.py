"""`segmin train`; also `torchrun --nproc-per-node N -m segmin.train.cli ...`."""

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


def main(argv: list[str] | None = None) -> int:
    """Entry for `python -m segmin.train.cli` (what torchrun launches): the same arguments as `segmin train`."""
    parser = CommandParser(prog="segmin.train.cli", description="segmin training (torchrun entry)")
    _add_train_arguments(parser)
    args = parser.parse_args(argv)
    show_progress()
    return _train(args)


if __name__ == "__main__":
    sys.exit(main())
