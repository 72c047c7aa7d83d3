"""`segmin replay`: the robot runtime over a recorded sequence, configured by a follower config
(`--follower FILE` and `KEY=VALUE`, the keys of nav-eval's `follower:` and the ROS 2 node's)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from segmin.common.cli_args import add_overrides, overrides_of
from segmin.nav_eval.live.options import add_live_options, live_view
from segmin.nav_eval.runtime.methods import DEPTH_METHODS, METHODS

if TYPE_CHECKING:
    from segmin.nav_eval.replay.imu import ImuTrack
    from segmin.nav_eval.replay.run import FrameSource
    from segmin.nav_eval.runtime.camera import CameraGeometry
    from segmin.nav_eval.runtime.follower_config import FollowerConfig

# The flags that set one follower key each (flag: key, type, help): shortcuts, applied before the
# KEY=VALUE overrides.
SHORTCUTS: dict[str, tuple[str, type, str]] = {
    "method": ("method", str, "the navigation method (default: the config's, segmind)"),
    "depth_threshold": ("navigator.depth_threshold", float, "depth cut d_th in metres (paper: 5, 8, 10)"),
    "mask_closing": (
        "navigator.mask_closing",
        int,
        "close each mask with a disc of this radius (px at 224 px of width, whatever the frames' size) before the "
        "fusion (0: the paper's; 8 with the shipped trees model)",
    ),
    "segment_hz": ("runtime.segment_hz", int, "segmentation rate (20, the paper's)"),
    "command_hz": ("runtime.command_hz", int, "command rate, divides the segmentation rate (5)"),
}


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    replay = commands.add_parser(
        "replay",
        help="run the robot runtime over a recorded sequence (frames, video or a ROS bag): commands.csv, plot, "
        "overlay video",
        description="Runs RowFollower (the runtime a robot runs, at the paper's 20 Hz masks / 5 Hz commands) "
        "over a folder of RGB frames (with optional aligned uint16 millimetre depth PNGs or float metre .npy "
        "named alike), a video, or the colour (and depth) topics of a ROS bag (times from the header stamps), and writes commands.csv, overlay.mp4 and commands.png (the plot needs the "
        "[sim] extra). Without depth SegMin runs on the mask alone; SegMinD and SegCorridor need depth. The runtime is set "
        "up by a follower config (--follower FILE, then KEY=VALUE overrides such as navigator.depth_threshold=8: the "
        "keys of nav-eval's follower section and of the ROS 2 node's follower parameters); SegCorridor takes the "
        "camera from the bag's CameraInfo or from the config's camera section, and its roll and pitch from the "
        "bag's IMU.",
    )
    replay.add_argument(
        "--model",
        required=True,
        help="exported .onnx (or LiteRT .tflite) file or a shipped model name (vineyards, trees)",
    )
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
    replay.add_argument(
        "--follower",
        type=Path,
        default=None,
        help="follower config YAML (method, navigator, runtime, camera), or a ROS 2 parameter file with a follower "
        "section such as the shipped jackal_d435.yaml (segmin configs copy jackal_d435; default: the defaults, method "
        "segmind)",
    )
    for flag, (key, kind, what) in SHORTCUTS.items():
        choices = METHODS if flag == "method" else None
        replay.add_argument(
            f"--{flag.replace('_', '-')}", type=kind, choices=choices, help=f"{what}; shortcut for {key}=..."
        )
    replay.add_argument(
        "--camera-info-topic",
        default=None,
        help="with --bag, SegCorridor: the CameraInfo topic of its intrinsics (default: camera_info beside --rgb-topic)",
    )
    replay.add_argument(
        "--imu-topic",
        default=None,
        help="with --bag, SegCorridor: the sensor_msgs/Imu topic whose roll and pitch level its depth points, each "
        "frame with the newest sample at or before it, as the node does (default: /imu/data when the bag has it, "
        "else level ground)",
    )
    replay.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default 2)")
    add_live_options(replay)
    replay.add_argument("--out", type=Path, required=True, help="output folder (must be empty unless --force)")
    replay.add_argument("--force", action="store_true", help="write into a non-empty --out")
    add_overrides(replay, example="navigator.depth_threshold=8")
    replay.set_defaults(func=_replay)


def follower_of(args: argparse.Namespace) -> FollowerConfig:
    """The follower config of the command line: --follower, the shortcut flags, then KEY=VALUE.
    A bad depth cut given by its flag is named by the flag."""
    from segmin.common.config import ConfigError
    from segmin.nav_eval.runtime.follower_config import load_follower_config

    given = {flag: getattr(args, flag) for flag in SHORTCUTS if getattr(args, flag) is not None}
    depth_key = SHORTCUTS["depth_threshold"][0]
    overrides = [f"{SHORTCUTS[flag][0]}={value}" for flag, value in given.items()] + overrides_of(args)
    if args.follower is None and not any(o.startswith(f"{depth_key}=") for o in overrides):
        raise ValueError(
            "--depth-threshold: the depth cut in metres is needed (paper: 5, 8, 10), or navigator.depth_threshold=... "
            "or a --follower file"
        )
    try:
        return load_follower_config(args.follower, overrides)
    except ConfigError as exc:
        if "depth_threshold" in given and f"{depth_key}:" in str(exc):
            detail = str(exc).partition(f"{depth_key}: ")[2]
            raise ValueError(f"--depth-threshold {args.depth_threshold:g}: {detail}") from None
        raise


def _bag_camera(args: argparse.Namespace, follower: FollowerConfig) -> CameraGeometry | None:
    """SegCorridor's camera from the bag's CameraInfo, unless the config gives the intrinsics
    (None then, and for the paper's methods, which need no camera)."""
    if args.camera_info_topic is not None and args.bag is None:
        raise ValueError("--camera-info-topic goes with --bag")
    if follower.method != "segcorridor" or follower.camera.intrinsics_given or args.bag is None:
        return None
    from segmin.nav_eval.replay.bags import bag_camera, camera_info_topic

    return bag_camera(args.bag, args.camera_info_topic or camera_info_topic(args.rgb_topic), follower.camera)


def _bag_imu(args: argparse.Namespace, follower: FollowerConfig) -> ImuTrack | None:
    """SegCorridor's IMU from the bag: --imu-topic, or the node's default topic when the bag has
    it (None: level ground); None for the paper's methods, which take no attitude."""
    if args.imu_topic is not None and args.bag is None:
        raise ValueError("--imu-topic goes with --bag")
    if follower.method != "segcorridor" or args.bag is None:
        if args.imu_topic is not None:
            raise ValueError(f"--imu-topic: {follower.method} takes no IMU (only segcorridor levels its points)")
        return None
    from segmin.nav_eval.replay.bags import bag_imu
    from segmin.nav_eval.replay.imu import DEFAULT_IMU_TOPIC

    return bag_imu(args.bag, args.imu_topic or DEFAULT_IMU_TOPIC, named=args.imu_topic is not None)


def _bag_source(args: argparse.Namespace, method: str) -> FrameSource | None:
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
    if method in DEPTH_METHODS and args.depth_topic is None:
        raise ValueError(f"--method {method} needs --depth-topic (depth frames); without depth use segmin (mask alone)")
    from segmin.nav_eval.replay.bags import DEFAULT_SLOP_S, bag_frames

    return bag_frames(args.bag, args.rgb_topic, args.depth_topic, DEFAULT_SLOP_S if args.slop is None else args.slop)


def _replay(args: argparse.Namespace) -> int:
    from segmin.data.canopy_region import check_closing_radius
    from segmin.nav_eval.replay.run import replay

    if args.mask_closing is not None:
        check_closing_radius(args.mask_closing, "--mask-closing")  # named as the flag, before the bag is opened
    follower = follower_of(args)
    with live_view(args) as live:
        result = replay(
            args.model,
            args.rgb,
            args.out,
            follower=follower,
            camera=_bag_camera(args, follower),
            source=_bag_source(args, follower.method),
            imu=_bag_imu(args, follower),
            depth=args.depth,
            fps=args.fps,
            timestamps=args.timestamps,
            force=args.force,
            threads=args.threads,
            live=live,
        )
    valid = sum(row[4] for row in result.commands)
    print(f"replay: {result.frames} frames, {len(result.commands)} commands ({valid} valid) with {follower.method}")
    for note in result.notes:
        print(f"note: {note}")
    for path in result.files:
        print(f"wrote {path}")
    return 0
