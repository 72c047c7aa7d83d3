"""The live view's command-line options (`--live`, `--live-port`, replay's `--live-rate`) and the
server they start, shared by `segmin replay` and `segmin nav-eval`. Light at import: the CLI's
help must not load foxglove-sdk or rosbags."""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Iterator
from typing import Any

DEFAULT_PORT = 8765  # Foxglove's default for a WebSocket connection
LAYOUT = "configs/foxglove/segmin_live.json"


def add_live_options(parser: argparse.ArgumentParser, rate: bool = True) -> None:
    """--live and --live-port (and, with `rate`, --live-rate) on `parser`."""
    parser.add_argument(
        "--live",
        action="store_true",
        help="stream the camera with the mask and target, the histogram, the command, SegCorridor's rows and the "
        f"path to Foxglove on ws://127.0.0.1:PORT (needs the [live] extra; layout: {LAYOUT})",
    )
    parser.add_argument(
        "--live-port", type=int, default=None, help=f"with --live: the WebSocket port (default {DEFAULT_PORT})"
    )
    if rate:
        parser.add_argument(
            "--live-rate",
            type=float,
            default=None,
            help="with --live: play at this multiple of the recording's speed (1: its own; default: as fast as it runs)",
        )


def live_port(args: argparse.Namespace) -> int:
    """The port `--live` serves on, checked free (0: no --live); --live-port and --live-rate
    without --live are refused, named."""
    if not args.live:
        for option in ("live_port", "live_rate"):
            if getattr(args, option, None) is not None:
                raise ValueError(f"--{option.replace('_', '-')} goes with --live")
        return 0
    from segmin.nav_eval.live.server import check_port

    port = DEFAULT_PORT if args.live_port is None else args.live_port
    check_port(port, "--live-port")
    return port


@contextlib.contextmanager
def live_view(args: argparse.Namespace) -> Iterator[Any]:
    """Replay's `LiveView` serving for the duration of the block with --live (the port checked
    first, the URL printed; with --bag, the path and TF from its /odom when it has one); None
    without --live."""
    port = live_port(args)
    if not port:
        yield None
        return
    from segmin.nav_eval.live.publisher import LiveView
    from segmin.nav_eval.live.server import LIVE_TYPES, ODOMETRY_TYPES, LiveServer
    from segmin.nav_eval.ros2.topics import ODOM

    poses: list = []
    if args.bag is not None:
        from segmin.nav_eval.replay.bags import bag_poses

        poses = bag_poses(args.bag, ODOM)
    with LiveServer({**LIVE_TYPES, **ODOMETRY_TYPES} if poses else LIVE_TYPES, port) as server:
        view = LiveView(server, args.live_rate, poses)
        path = "" if poses else f" (no {ODOM} odometry in the input: no path)"
        print(f"live view: ws://127.0.0.1:{server.port}{path}; Foxglove layout: {LAYOUT}", flush=True)
        yield view
