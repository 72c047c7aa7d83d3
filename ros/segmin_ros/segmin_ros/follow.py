"""`ros2 run segmin_ros follow --params FILE [--ros-args ...]`: segmin's row-follower node.

A thin entry point: the node, its parameter checks and its one-line errors are segmin's own
(`segmin ros2 follow`), installed from pip, so a colcon workspace and `pip install 'segmin[ros]'`
run the same code. The parameter file is read by segmin before rclpy starts (a bad value refuses
to start, naming the parameter), hence `--params` rather than ROS's `--params-file`.
"""

from __future__ import annotations

import sys

SEGMIN_MISSING = "segmin_ros needs segmin in the Python of the robot's ROS 2: pip install 'segmin[ros]'"


def main(argv: list[str] | None = None) -> int:
    """Run `segmin ros2 follow` with this executable's arguments."""
    try:
        from segmin.app.cli import main as segmin_main
    except ModuleNotFoundError as exc:
        if (exc.name or "").split(".")[0] != "segmin":
            raise
        print(f"follow: error: {SEGMIN_MISSING}", file=sys.stderr)
        return 2
    return segmin_main(["ros2", "follow", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
