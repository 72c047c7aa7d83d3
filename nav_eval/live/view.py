"""The live view's own topics as ROS 2 messages, built here once for the live publisher and for
the bags nav-eval writes, so that a live session and a recorded run carry the same topics in the
same schemas and one Foxglove layout opens both.

| topic | type | frame | what |
| --- | --- | --- | --- |
| /segmin/overlay | sensor_msgs/Image rgb8 | camera_color_optical_frame | each camera frame, at most 224 px wide, with the newest command's fused mask (green) and target column (red; a red bar on top: a stop) |
| /segmin/histogram | std_msgs/Float32MultiArray | | the command's smoothed column histogram (SegMin, SegMinD, SegZeros; SegCorridor's fallback), one value per column; empty otherwise |
| /segmin/rows | visualization_msgs/MarkerArray | base_link | SegCorridor's centreline and the rows half its running corridor width to each side; a DELETEALL without a centreline (the paper's methods, the fallback) |
| /segmin/path | nav_msgs/Path | odom | the robot's newest poses, one per command (at most `PATH_POSES`) |

The overlay is drawn by `replay.video.overlay` (the video's drawing), nothing of its own, on the
frame scaled down to at most `OVERLAY_WIDTH` (what the shipped models see): a view to watch the
navigator by, at an eighth of a 640 px frame's drawing, serialising and sending (the full frame is
the camera topic's). A topic no one
asks for (`wanted`: the live view's subscriptions) is not built. The messages use the ROS 2
Humble types of `rosbags` (the [ros] or [live] extra).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from segmin.nav_eval.replay.video import overlay
from segmin.nav_eval.ros2.topics import BASE_FRAME, HISTOGRAM, ODOM_FRAME, OPTICAL_FRAME, OVERLAY, PATH, ROWS
from segmin.nav_eval.runtime.corridor.row_fit import polyval
from segmin.nav_eval.runtime.follower import FollowerOutput

VIEW_TYPES = {
    OVERLAY: "sensor_msgs/msg/Image",
    HISTOGRAM: "std_msgs/msg/Float32MultiArray",
    ROWS: "visualization_msgs/msg/MarkerArray",
    PATH: "nav_msgs/msg/Path",
}
OVERLAY_WIDTH = 224  # px, the shipped models' input width: frames wider than this are scaled down before drawing
ROW_SAMPLES = 12  # points per drawn line: enough for a quadratic centreline to look smooth
LINE_WIDTH_M = 0.05
MARKER_LINE_STRIP, MARKER_ADD, MARKER_DELETEALL = 4, 0, 3  # visualization_msgs/Marker constants
# Poses a path message carries: 10 min of commands at 5 Hz. The whole path of an hour's run would
# make each message, and its serialising, grow with the run's length.
PATH_POSES = 3000


def nanoseconds(t: float) -> int:
    """A time in seconds as the integer nanoseconds of a log time and a stamp."""
    return round(t * 1e9)


def header(types: Any, t: float, frame_id: str) -> Any:
    """A std_msgs/Header stamped `t` seconds in `frame_id`."""
    ns = nanoseconds(t)
    stamp = types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


def image_message(types: Any, head: Any, pixels: np.ndarray, encoding: str) -> Any:
    """A sensor_msgs/Image of `pixels` (rgb8 H x W x 3 uint8, 32FC1 H x W float32...)."""
    pixels = np.ascontiguousarray(pixels)
    height, width = pixels.shape[:2]
    data = pixels.view(np.uint8).reshape(-1)
    return types["sensor_msgs/msg/Image"](
        header=head, height=height, width=width, encoding=encoding, is_bigendian=0, step=data.size // height, data=data
    )


def twist(types: Any, v: float, omega: float) -> Any:
    """The geometry_msgs/Twist of a command (v forward, omega about z), as /cmd_vel carries it."""
    vector = types["geometry_msgs/msg/Vector3"]
    return types["geometry_msgs/msg/Twist"](linear=vector(x=v, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=omega))


class ViewMessages:
    """The view topics' messages of one run: `step` per runtime step; it keeps the newest
    command's mask and target for the frames between commands, and the path so far."""

    def __init__(self, types: Any) -> None:
        self._types = types
        self._mask: np.ndarray | None = None
        self._column: float | None = None
        self._poses: deque[Any] = deque(maxlen=PATH_POSES)

    def step(
        self,
        t: float,
        rgb: np.ndarray | None,
        output: FollowerOutput,
        navigator: Any,
        pose: Any | None = None,
        wanted: Callable[[str], bool] = lambda topic: True,
    ) -> list[tuple[str, Any]]:
        """(topic, message) of one runtime step at `t`: the overlay of `rgb` (none without an
        image) and, at a fresh command, its histogram, its rows (from `navigator`'s running
        corridor width) and the path with `pose` (a geometry_msgs/Pose in odom; None: no path);
        only the topics `wanted` (the path's poses are kept all the same)."""
        messages: list[tuple[str, Any]] = []
        if output.fresh:
            self._mask = output.fused
            self._column = output.command.target_column
        if rgb is not None and wanted(OVERLAY):
            messages.append((OVERLAY, self.overlay(t, rgb)))
        if not output.fresh:
            return messages
        if wanted(HISTOGRAM):
            messages.append((HISTOGRAM, self.histogram(output.command.histogram)))
        if wanted(ROWS):
            messages.append((ROWS, self.rows(t, getattr(output.command, "centre", None), navigator)))
        if pose is not None:
            path = self.path(t, pose)
            if wanted(PATH):
                messages.append((PATH, path))
        return messages

    def overlay(self, t: float, rgb: np.ndarray) -> Any:
        """The frame, scaled to at most `OVERLAY_WIDTH` wide, with the newest mask and column drawn."""
        height, width = rgb.shape[:2]
        mask = self._mask if self._mask is not None and self._mask.shape == (height, width) else None
        column = self._column
        if width > OVERLAY_WIDTH:
            scale = OVERLAY_WIDTH / width
            size = (OVERLAY_WIDTH, max(1, round(height * scale)))
            rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_LINEAR)  # INTER_AREA: 10x the CPU at 640 -> 224
            if mask is not None:
                mask = cv2.resize(np.ascontiguousarray(mask).view(np.uint8), size, interpolation=cv2.INTER_NEAREST)
                mask = mask.view(bool)
            column = None if column is None else column * scale
        drawn = overlay(rgb, mask, column)
        return image_message(self._types, header(self._types, t, OPTICAL_FRAME), drawn, "rgb8")

    def histogram(self, values: np.ndarray) -> Any:
        """The histogram as a Float32MultiArray of one dimension, "column"."""
        types = self._types
        data = np.asarray(values, dtype=np.float32).reshape(-1)
        size = int(data.size)
        dim = types["std_msgs/msg/MultiArrayDimension"](label="column", size=size, stride=size)
        layout = types["std_msgs/msg/MultiArrayLayout"](dim=[dim], data_offset=0)
        return types["std_msgs/msg/Float32MultiArray"](layout=layout, data=data)

    def rows(self, t: float, centre: tuple[float, ...] | None, navigator: Any) -> Any:
        """SegCorridor's centreline (green) and rows (orange, with a known corridor width) between
        its x_min and x_max; one DELETEALL marker without a centreline, so no stale line stays."""
        types = self._types
        if centre is None:
            return types["visualization_msgs/msg/MarkerArray"](
                markers=[self._marker(t, 0, MARKER_DELETEALL, [], (0, 0, 0))]
            )
        config = navigator.config
        x = np.linspace(float(config.x_min), float(config.x_max), ROW_SAMPLES)
        y = np.asarray(polyval(x, centre), dtype=float)
        lines = [(y, (0.1, 0.9, 0.1))]
        width = getattr(navigator, "corridor_width", None)
        if width is not None:
            lines += [(y + width / 2.0, (1.0, 0.5, 0.0)), (y - width / 2.0, (1.0, 0.5, 0.0))]
        point = types["geometry_msgs/msg/Point"]
        markers = [
            self._marker(t, k, MARKER_ADD, [point(x=float(a), y=float(b), z=0.0) for a, b in zip(x, ys)], colour)
            for k, (ys, colour) in enumerate(lines)
        ]
        return types["visualization_msgs/msg/MarkerArray"](markers=markers)

    def path(self, t: float, pose: Any) -> Any:
        """The path in odom: its newest `PATH_POSES` poses, `pose` the last."""
        types = self._types
        self._poses.append(types["geometry_msgs/msg/PoseStamped"](header=header(types, t, ODOM_FRAME), pose=pose))
        return types["nav_msgs/msg/Path"](header=header(types, t, ODOM_FRAME), poses=list(self._poses))

    def _marker(self, t: float, key: int, action: int, points: list[Any], colour: tuple[float, float, float]) -> Any:
        types = self._types
        vector = types["geometry_msgs/msg/Vector3"]
        identity = types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
            orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        )
        texture = types["sensor_msgs/msg/CompressedImage"](
            header=header(types, 0.0, ""), format="", data=np.zeros(0, dtype=np.uint8)
        )
        mesh = types["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, dtype=np.uint8))
        return types["visualization_msgs/msg/Marker"](
            header=header(types, t, BASE_FRAME),
            ns="segmin_rows",
            id=key,
            type=MARKER_LINE_STRIP,
            action=action,
            pose=identity,
            scale=vector(x=LINE_WIDTH_M, y=0.0, z=0.0),
            color=types["std_msgs/msg/ColorRGBA"](r=colour[0], g=colour[1], b=colour[2], a=1.0),
            lifetime=types["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
            frame_locked=False,
            points=points,
            colors=[],
            texture_resource="",
            texture=texture,
            uv_coordinates=[],
            text="",
            mesh_resource="",
            mesh_file=mesh,
            mesh_use_embedded_materials=False,
        )
