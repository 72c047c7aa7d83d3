"""What `segmin replay --live` and the node's `live.port` stream: per runtime step the view topics
(`live.view`) and, at each command, /cmd_vel, on a `LiveServer`.

The messages go out as the runtime produces them: a replay runs as fast as it can unless
`rate` paces it (1.0: the recording's own speed, 2.0: twice as fast), so that a person can
watch; pacing only waits before a frame, it never drops one.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from segmin.nav_eval.live.server import LiveServer
from segmin.nav_eval.live.view import ViewMessages, twist
from segmin.nav_eval.ros2 import topics
from segmin.nav_eval.runtime.follower import FollowerOutput


class LiveView:
    """The view of one run on `server`; `step` after every runtime step (see the module docstring)."""

    def __init__(self, server: LiveServer, rate: float | None = None) -> None:
        if rate is not None and not rate > 0:
            raise ValueError(f"--live-rate {rate}: a playback speed must be > 0 (1 = the recording's own)")
        self.server = server
        self._types = server.store.types
        self._view = ViewMessages(self._types)
        self._rate = rate
        self._start: tuple[float, float] | None = None  # (first frame's t, wall clock then)

    def step(
        self, t: float, rgb: np.ndarray | None, output: FollowerOutput, navigator: Any, pose: Any | None = None
    ) -> None:
        """Publish the step at `t` (after waiting for it with a `rate`): the overlay of `rgb`, and
        at a command its histogram, rows, /cmd_vel and (given `pose`, a Pose in odom) the path."""
        self._pace(t)
        for topic, message in self._view.step(t, rgb, output, navigator, pose, wanted=self.server.subscribed):
            self.server.write(topic, t, message)
        if output.fresh and self.server.subscribed(topics.CMD_VEL):
            self.server.write(topics.CMD_VEL, t, twist(self._types, output.command.v, output.command.omega))

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
