"""`segmin replay`: the robot runtime over a recorded sequence."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from segmin.nav_eval.replay.run import FrameSource


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    replay = commands.add_parser(
        "replay",
        help="run the robot runtime over a recorded sequence (frames, video or a ROS bag): commands.csv, plot, "
        "overlay video",
        description="Runs RowFollower (the runtime a robot runs, at the paper's 20 Hz masks / 5 Hz commands) "
        "over a folder of RGB frames (with optional aligned uint16 millimetre depth PNGs or float metre .npy "
        "named alike), a video, or the colour (and depth) topics of a ROS bag (times from the header stamps), and writes commands.csv, overlay.mp4 and commands.png (the plot needs the "
        "[sim] extra). Without depth SegMin runs on the mask alone; SegMinD needs depth.",
    )
    replay.add_argument("--model", required=True, help="exported .onnx file or a shipped model name (vineyards, trees)")
    source = replay.add_mutually_exclusive_group(required=True)
    source.add_argument(
        "--rgb", type=Path, help="folder of RGB frames (natural name order: f_2 before f_10) or a video file"
    )
    source.add_argument(
        "--bag", type=Path, help="ROS 1 .bag file or rosbag2 folder (sqlite3 or MCAP; needs the [ros] extra)"
    )
    replay.add_argument("--rgb-topic", help="with --bag: colour topic (sensor_msgs Image or CompressedImage)")
    replay.add_argument("--depth-topic", help="with --bag: aligned depth topic (16UC1 mm, 32FC1 m, compressedDepth)")
    replay.add_argument(
        "--slop", type=float, default=None, help="with --bag: colour/depth stamp pairing tolerance in s (default 0.01)"
    )
    replay.add_argument(
        "--depth",
        type=Path,
        default=None,
        help="folder of depth frames named like the RGB frames: uint16 PNG in millimetres (0 = no reading) "
        "or float .npy in metres (NaN = no reading; values above 1000 are refused as millimetres)",
    )
    timing = replay.add_mutually_exclusive_group()
    timing.add_argument("--fps", type=float, default=None, help="frame rate: frame i at i / fps seconds")
    timing.add_argument("--timestamps", type=Path, default=None, help="file of one timestamp (s) per frame")
    replay.add_argument("--method", default="segmind", choices=("segmin", "segmind", "segzeros"))
    replay.add_argument(
        "--depth-threshold", type=float, required=True, help="depth cut d_th in metres (paper: 5, 8, 10)"
    )
    replay.add_argument(
        "--mask-closing",
        type=int,
        default=0,
        help="close each mask with a disc of this radius (px at 224 px of width, whatever the frames' size) before "
        "the fusion (default 0: the paper's; 8 with the shipped trees model)",
    )
    replay.add_argument("--segment-hz", type=int, default=20, help="segmentation rate (default 20, the paper's)")
    replay.add_argument("--command-hz", type=int, default=5, help="command rate, divides --segment-hz (default 5)")
    replay.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default 2)")
    replay.add_argument("--out", type=Path, required=True, help="output folder (must be empty unless --force)")
    replay.add_argument("--force", action="store_true", help="write into a non-empty --out")
    replay.set_defaults(func=_replay)


def _bag_source(args: argparse.Namespace) -> FrameSource | None:
    """The bag's `FrameSource` for --bag (None without); the bag-only options are checked here."""
    if args.bag is None:
        for option in ("rgb_topic", "depth_topic", "slop"):
            if getattr(args, option) is not None:
                raise ValueError(f"--{option.replace('_', '-')} goes with --bag")
        return None
    for option, value in (("--depth", args.depth), ("--fps", args.fps), ("--timestamps", args.timestamps)):
        if value is not None:
            raise ValueError(f"{option} does not go with --bag (times and depth come from the bag's topics)")
    if not args.rgb_topic:
        raise ValueError("--bag needs --rgb-topic (the colour topic)")
    if args.method == "segmind" and args.depth_topic is None:
        raise ValueError("--method segmind needs --depth-topic (depth frames); without depth use segmin (mask alone)")
    from segmin.nav_eval.replay.bags import DEFAULT_SLOP_S, bag_frames

    return bag_frames(args.bag, args.rgb_topic, args.depth_topic, DEFAULT_SLOP_S if args.slop is None else args.slop)


def _replay(args: argparse.Namespace) -> int:
    from segmin.data.canopy_region import check_closing_radius
    from segmin.nav_eval.replay.run import replay
    from segmin.nav_eval.runtime.follower import RuntimeConfig

    check_closing_radius(args.mask_closing, "--mask-closing")  # named as the flag, before the bag is opened
    runtime = RuntimeConfig(segment_hz=args.segment_hz, command_hz=args.command_hz)
    if args.depth_threshold > runtime.checks.max_depth_m:  # refused by the runtime too, later and unnamed
        raise ValueError(
            f"--depth-threshold {args.depth_threshold:g}: beyond the sensor's range "
            f"({runtime.checks.max_depth_m:g} m, max_depth_m), where a reading is no reading"
        )
    result = replay(
        args.model,
        args.rgb,
        args.out,
        source=_bag_source(args),
        method=args.method,
        depth_threshold=args.depth_threshold,
        mask_closing=args.mask_closing,
        depth=args.depth,
        fps=args.fps,
        timestamps=args.timestamps,
        force=args.force,
        runtime=runtime,
        threads=args.threads,
    )
    valid = sum(row[4] for row in result.commands)
    print(f"replay: {result.frames} frames, {len(result.commands)} commands ({valid} valid) with {args.method}")
    for note in result.notes:
        print(f"note: {note}")
    for path in result.files:
        print(f"wrote {path}")
    return 0
