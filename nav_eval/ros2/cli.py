"""`segmin ros2 follow` (the row-follower node), `segmin ros2 params` (its parameter file) and
`segmin ros2 view-bag` (a picture of a bag's topics).

rclpy is imported only by `follow`, so `segmin --help`, `params` and `view-bag` work without it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from segmin.nav_eval.ros2 import topics
from segmin.nav_eval.ros2.params import NODE_NAME
from segmin.nav_eval.runtime.methods import METHODS

RCLPY_MISSING = (
    "segmin ros2 follow needs rclpy and the ROS 2 message packages: source the robot's ROS 2 "
    "(source /opt/ros/<distro>/setup.bash) or, in a virtual environment of its own, "
    "pip install 'ros-rclpy[fastrtps]' ros-sensor-msgs ros-geometry-msgs ros-std-msgs ros-std-srvs ros-diagnostic-msgs"
)


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    ros2 = commands.add_parser(
        "ros2",
        help="the ROS 2 row-follower node and its parameter file",
        description="segmin on the robot's ROS 2: `follow` runs the node (colour + aligned depth in, cmd_vel "
        "out, on the same runtime as nav-eval and replay); `params` writes its parameter file with the defaults.",
    )
    sub = ros2.add_subparsers(dest="ros2_command", metavar="COMMAND", required=True)
    follow = sub.add_parser(
        "follow",
        help="run the row-follower node (needs rclpy: a sourced ROS 2 or the ROS 2 wheels)",
        description="Runs the row-follower node with the parameters of PARAMS (a standard ROS 2 parameter file, "
        "`node_name: ros__parameters: ...`; see `segmin ros2 params`). Driving is off until the ~/enable service "
        "(std_srvs/SetBool) or the `enabled` parameter turns it on. A bad parameter or model refuses to start.",
    )
    follow.add_argument("--params", type=Path, required=True, help="ROS 2 parameter file (YAML)")
    follow.add_argument(
        "--ros-args", nargs=argparse.REMAINDER, default=[], help="the rest goes to ROS (remappings, log level, ...)"
    )
    follow.set_defaults(func=_follow)
    params = sub.add_parser(
        "params",
        help="write the node's parameter file with every default (commented)",
        description="Writes a ROS 2 parameter file of the node's parameters with their defaults and descriptions "
        "(to stdout, or --out). Set `model` and `follower.navigator.depth_threshold` for your robot and field.",
    )
    params.add_argument(
        "--method",
        default="segmind",
        choices=METHODS,
        help="the navigation method, which chooses the navigator's parameters (default segmind)",
    )
    params.add_argument("--out", type=Path, default=None, help="file to write (default: stdout)")
    params.add_argument("--node-name", default=NODE_NAME, help=f"node name of the section (default {NODE_NAME})")
    params.set_defaults(func=_params)
    _register_view_bag(sub)

    b = bench.add_parser(
        "ros2",
        help="the node fed a bag at 30 Hz: latency, command jitter, memory (needs rclpy; a loopback-only namespace)",
    )
    b.add_argument("--model", type=Path, required=True, help="exported .onnx file or a shipped model name")
    b.add_argument("--bag", type=Path, required=True, help="a bag with segmin's camera topics (nav-eval --bag)")
    b.add_argument("--seconds", type=float, default=60.0, help="how long to feed the node (default 60)")
    b.add_argument("--threads", type=int, default=2, help="onnxruntime threads of the node (default 2)")
    b.add_argument("--method", default="segmind", choices=("segmin", "segmind", "segzeros"))
    b.add_argument("--depth-threshold", type=float, default=5.0, help="depth cut in metres (default 5)")
    b.add_argument(
        "--at-once", action="store_true", help="publish_on_timer false: the node publishes each command when computed"
    )
    b.add_argument(
        "--inference-spin", action="store_true", help="the node's inference_spin: onnxruntime threads busy-wait"
    )
    b.add_argument(
        "--command-priority",
        type=int,
        default=0,
        help="the node's command_priority: SCHED_FIFO priority of its command thread (default 0: normal)",
    )
    b.set_defaults(func=_bench)


def _register_view_bag(sub: argparse._SubParsersAction) -> None:
    view = sub.add_parser(
        "view-bag",
        help="a picture of a bag's camera, depth, cmd_vel and odometry topics (what a viewer shows)",
        description="Renders one PNG of a bag (e.g. from `segmin nav-eval --bag`): the colour frame nearest --at "
        "(with --model, the mask the node would compute over it), its aligned depth, /cmd_vel over the bag and "
        "the top-down path of /odom: the panels Foxglove or RViz would show, rendered by segmin.",
    )
    view.add_argument("--bag", type=Path, required=True, help="a ROS 1 bag or rosbag2 folder")
    view.add_argument("--out", type=Path, required=True, help="PNG to write")
    view.add_argument("--at", type=float, default=0.0, help="seconds into the bag of the frame shown (default 0)")
    view.add_argument(
        "--model", type=Path, default=None, help="exported .onnx or a shipped model name: tint its mask over the frame"
    )
    view.add_argument("--colour-topic", default=topics.COLOUR, help=f"default {topics.COLOUR}")
    view.add_argument("--depth-topic", default=topics.DEPTH, help=f"default {topics.DEPTH}")
    view.add_argument("--force", action="store_true", help="overwrite --out")
    view.set_defaults(func=_view_bag)


def _follow(args: argparse.Namespace) -> int:
    from segmin.nav_eval.ros2.params import load_params_file

    name, values = load_params_file(args.params)
    try:
        from segmin.nav_eval.ros2 import node
    except ModuleNotFoundError as exc:
        if (exc.name or "").split(".")[0] in ("segmin", "numpy", "cv2", "yaml"):
            raise
        print(f"segmin: error: {RCLPY_MISSING} (module {exc.name!r} is missing)", file=sys.stderr)
        return 2
    return node.run(name, values, args.params.resolve().parent, args.ros_args)


def _bench(args: argparse.Namespace) -> int:
    try:
        import rclpy  # noqa: F401
    except ModuleNotFoundError:
        print(f"segmin: error: {RCLPY_MISSING.replace('ros2 follow', 'bench ros2')}", file=sys.stderr)
        return 2
    from segmin.nav_eval.ros2.bench import bench_ros2

    try:
        print(
            bench_ros2(
                args.model,
                args.bag,
                args.seconds,
                args.threads,
                args.method,
                args.depth_threshold,
                not args.at_once,
                args.command_priority,
                args.inference_spin,
            )
        )
    except RuntimeError as exc:  # the node gave nothing to measure: one line, not a traceback
        print(f"segmin: bench ros2: {exc}", file=sys.stderr)
        return 1
    return 0


def _view_bag(args: argparse.Namespace) -> int:
    from segmin.common.atomic import write_bytes
    from segmin.common.outputs import check_output_file
    from segmin.nav_eval.ros2.bag_view import plot_bag_view, read_bag_view

    out = check_output_file(args.out)
    if out.exists() and not args.force:
        raise ValueError(f"--out {out}: already exists (use --force to overwrite)")
    if not args.at >= 0:
        raise ValueError(f"--at must be a number of seconds >= 0, got {args.at!r}")
    view = read_bag_view(args.bag, args.at, args.colour_topic, args.depth_topic)
    mask = None
    if args.model is not None:
        from segmin.nav_eval.runtime.segmenter import OnnxSegmenter

        mask = OnnxSegmenter(args.model).segment(view.rgb)
    write_bytes(out, plot_bag_view(view, f"{args.bag.name}: segmin's rendering of the bag's topics", mask))
    print(f"wrote {out}")
    return 0


def _params(args: argparse.Namespace) -> int:
    from segmin.common.atomic import write_text
    from segmin.nav_eval.ros2.params import defaults_yaml

    text = defaults_yaml(args.node_name, args.method)
    if args.out is None:
        sys.stdout.write(text)
    else:
        write_text(args.out, text)
        print(f"wrote {args.out}")
    return 0
