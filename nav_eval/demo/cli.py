"""`segmin navigate-demo`: the navigators on analytic row scenes (no simulator, no model)."""

from __future__ import annotations

import argparse


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    demo = commands.add_parser(
        "navigate-demo",
        help="run SegMin, SegMinD and SegZeros on analytic row scenes and draw the histograms",
        description="Builds a few synthetic mask + depth frames in memory (no simulator), runs the three "
        "navigators and writes navigator_demo.png (like the paper's Figure 4) and summary.txt.",
    )
    demo.add_argument("--out", default="runs/demo", help="output folder (default: runs/demo)")
    demo.add_argument("--size", type=int, default=224, help="frame size in pixels (default: 224)")
    demo.add_argument(
        "--no-figure", action="store_true", help="only the text summary (the figure needs the [sim] extra's matplotlib)"
    )
    demo.set_defaults(func=_navigate_demo)


def _navigate_demo(args: argparse.Namespace) -> int:
    from segmin.nav_eval.demo.run import run_demo

    if args.size < 32:
        raise ValueError(f"--size must be at least 32 pixels, got {args.size}")
    figure, summary, _ = run_demo(args.out, size=args.size, figure=not args.no_figure)
    print(summary.read_text(), end="")
    if figure is not None:
        print(f"figure: {figure}")
    print(f"summary: {summary}")
    return 0
