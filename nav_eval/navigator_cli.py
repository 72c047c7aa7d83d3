"""Robot-side commands: `segmin navigate-demo`, `segmin replay` and `segmin bench navigator`."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    demo = commands.add_parser(
        "navigate-demo",
        help="run SegMin, SegMinD and SegZeros on analytic row scenes and draw the histograms",
        description="Builds a few synthetic mask + depth frames in memory (no simulator), runs the three "
        "navigators and writes navigator_demo.png (like the paper's Figure 4) and summary.txt.",
    )
    demo.add_argument("--out", default="runs/demo", help="output folder (default: runs/demo)")
    demo.add_argument("--size", type=int, default=224, help="frame size in pixels (default: 224)")
    demo.add_argument("--no-figure", action="store_true",
                      help="only the text summary (the figure needs the [sim] extra's matplotlib)")
    demo.set_defaults(func=_navigate_demo)

    replay = commands.add_parser(
        "replay",
        help="run the robot runtime over a recorded sequence (frames or video): commands.csv, plot, overlay video",
        description="Runs RowFollower (the runtime a robot runs, at the paper's 20 Hz masks / 5 Hz commands) "
        "over a folder of RGB frames (with optional aligned uint16 millimetre depth PNGs or float metre .npy "
        "named alike) or a video, and writes commands.csv, overlay.mp4 and commands.png (the plot needs the "
        "[sim] extra). Without depth SegMin runs on the mask alone; SegMinD needs depth.",
    )
    replay.add_argument("--model", required=True, help="exported .onnx file")
    replay.add_argument("--rgb", type=Path, required=True, help="folder of RGB frames (name order) or a video file")
    replay.add_argument("--depth", type=Path, default=None, help="folder of depth frames named like the RGB frames")
    timing = replay.add_mutually_exclusive_group()
    timing.add_argument("--fps", type=float, default=None, help="frame rate: frame i at i / fps seconds")
    timing.add_argument("--timestamps", type=Path, default=None, help="file of one timestamp (s) per frame")
    replay.add_argument("--method", default="segmind", choices=("segmin", "segmind", "segzeros"))
    replay.add_argument("--depth-threshold", type=float, required=True, help="depth cut d_th in metres (paper: 5, 8, 10)")
    replay.add_argument("--segment-hz", type=int, default=20, help="segmentation rate (default 20, the paper's)")
    replay.add_argument("--command-hz", type=int, default=5, help="command rate, divides --segment-hz (default 5)")
    replay.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default 2)")
    replay.add_argument("--out", type=Path, required=True, help="output folder (must be empty unless --force)")
    replay.add_argument("--force", action="store_true", help="write into a non-empty --out")
    replay.set_defaults(func=_replay)

    nav = bench.add_parser("navigator", help="time Navigator.step per method, and the runtime per frame, on one thread")
    nav.add_argument("--size", type=int, default=224)
    nav.add_argument("--steps", type=int, default=3000)
    nav.add_argument("--model", default=None,
                     help="ONNX file for the full runtime step (default: an untrained model exported to a temp file, "
                     "needs the [train] extra; skipped without it)")
    nav.add_argument("--threads", type=int, default=2, help="onnxruntime threads for the full step (default 2)")
    nav.set_defaults(func=_bench_navigator)


def _navigate_demo(args: argparse.Namespace) -> int:
    from segmin.nav_eval.demo import run_demo

    if args.size < 32:
        raise ValueError(f"--size must be at least 32 pixels, got {args.size}")
    figure, summary, _ = run_demo(args.out, size=args.size, figure=not args.no_figure)
    print(summary.read_text(), end="")
    if figure is not None:
        print(f"figure: {figure}")
    print(f"summary: {summary}")
    return 0


def _replay(args: argparse.Namespace) -> int:
    from segmin.nav_eval.replay import replay
    from segmin.nav_eval.runtime import RuntimeConfig

    result = replay(args.model, args.rgb, args.out, method=args.method, depth_threshold=args.depth_threshold,
                    depth=args.depth, fps=args.fps, timestamps=args.timestamps, force=args.force,
                    runtime=RuntimeConfig(segment_hz=args.segment_hz, command_hz=args.command_hz),
                    threads=args.threads)
    valid = sum(row[4] for row in result.commands)
    print(f"replay: {result.frames} frames, {len(result.commands)} commands ({valid} valid) with {args.method}")
    for note in result.notes:
        print(f"note: {note}")
    for path in result.files:
        print(f"wrote {path}")
    return 0


def _bench_navigator(args: argparse.Namespace) -> int:
    from segmin.nav_eval.navigator_bench import bench_navigator, bench_runtime, format_rows, single_thread_environment

    single_thread_environment()
    print(format_rows(bench_navigator(size=args.size, steps=args.steps), args.size))
    print(bench_runtime(size=args.size, steps=args.steps, model=args.model, threads=args.threads))
    return 0
