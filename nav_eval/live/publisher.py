"""What `segmin replay --live` and the node's `live_port` stream: per runtime step the view topics
(`live.view`) and, at each command, /cmd_vel, on a `LiveServer`. Given the robot's odometry
(a bag's /odom: `poses`), also the path and odom -> base_link on /tf at each command, so that
Foxglove's 3D panel places SegCorridor's rows (in base_link) along the path.

The messages go out as the runtime produces them: a replay runs as fast as it can unless
`rate` paces it (1.0: the recording's own speed, 2.0: twice as fast), so that a person can
watch; pacing only waits before a frame, it never drops one.
"""

from __future__ import annotations

import bisect
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from segmin.nav_eval.live.server import LiveServer
from segmin.nav_eval.live.view import ViewMessages, header, twist
from segmin.nav_eval.ros2.topics import BASE_FRAME, CMD_VEL, ODOM_FRAME, TF
from segmin.nav_eval.runtime.follower import FollowerOutput

Pose = tuple[float, float, float, float, float, float, float]  # x, y, z, qx, qy, qz, qw in odom


class LiveView:
    """The view of one run on `server`; `step` after every runtime step (see the module docstring)."""

    def __init__(self, server: LiveServer, rate: float | None = None, poses: Sequence[tuple[float, Pose]] = ()) -> None:
        if rate is not None and not rate > 0:
            raise ValueError(f"--live-rate {rate}: a playback speed must be > 0 (1 = the recording's own)")
        self.server = server
        self._types = server.store.types
        self._view = ViewMessages(self._types)
        self._rate = rate
        self._start: tuple[float, float] | None = None  # (first frame's t, wall clock then)
        self._pose_stamps = [t for t, _ in poses]  # ascending
        self._poses = [pose for _, pose in poses]

    def step(self, t: float, rgb: np.ndarray | None, output: FollowerOutput, navigator: Any) -> None:
        """Publish the step at `t` (after waiting for it with a `rate`): the overlay of `rgb`, and
        at a command its histogram, rows, /cmd_vel and (with odometry) the path and /tf."""
        self._pace(t)
        pose = self._pose(t) if output.fresh else None
        for topic, message in self._view.step(t, rgb, output, navigator, pose, wanted=self.server.subscribed):
            self.server.write(topic, t, message)
        if output.fresh and self.server.subscribed(CMD_VEL):
            self.server.write(CMD_VEL, t, twist(self._types, output.command.v, output.command.omega))
        if pose is not None and self.server.subscribed(TF):
            self.server.write(TF, t, self._transform(t, pose))

    def _pose(self, t: float) -> Any | None:
        """The newest odometry pose at or before `t` as a geometry_msgs/Pose (None: none yet)."""
        where = bisect.bisect_right(self._pose_stamps, t) - 1
        if where < 0:
            return None
        x, y, z, qx, qy, qz, qw = self._poses[where]
        types = self._types
        return types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=x, y=y, z=z),
            orientation=types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
        )

    def _transform(self, t: float, pose: Any) -> Any:
        """odom -> base_link at `t` of an odometry pose, as /tf carries it."""
        types = self._types
        p = pose.position
        transform = types["geometry_msgs/msg/Transform"](
            translation=types["geometry_msgs/msg/Vector3"](x=p.x, y=p.y, z=p.z), rotation=pose.orientation
        )
        stamped = types["geometry_msgs/msg/TransformStamped"](
            header=header(types, t, ODOM_FRAME), child_frame_id=BASE_FRAME, transform=transform
        )
        return types["tf2_msgs/msg/TFMessage"](transforms=[stamped])

    def _pace(self, t: float) -> None:
        """Sleep until frame `t` is due at `rate` times the recording's speed (no `rate`: at once)."""
        if self._rate is None:
            return
        now = time.perf_counter()
        if self._start is None:
            self._start = (t, now)
            return
        due = self._start[1] + (t - self._start[0]) / self._rate
        if due > now:
            time.sleep(due - now)
