"""The IMU's attitude for SegCorridor, from `sensor_msgs/Imu` messages: for bag replay and the ROS 2 node alike.

`Imu` gives the orientation quaternion of the IMU in a level frame (REP 103 / REP 145: x
forward, y left, z up); the runtime wants (roll, pitch) of the body-to-level rotation
R_y(pitch) R_x(roll) (positive roll lifts the left side, positive pitch lowers the nose), which
is the quaternion's ZYX decomposition without its yaw. The IMU is taken to be mounted level
with the body (imu_link aligned with base_link, as on the Jackal). One decoder for both, so a
bag replayed offline and the same bag played to the node level the depth points alike.

`ImuTrack` is a bag's IMU for replay: each frame takes the newest sample stamped at or before
it, ignored (level ground, counted) when it is older than `IMU_MAX_AGE_S`, the node's default
`imu_max_age_s`; a message the node would ignore (no orientation, not a unit quaternion) is
skipped and counted. Fields are read by name, so rclpy's and rosbags' messages both work; no
ROS import (the bare robot install).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

QUATERNION_NORM_TOLERANCE = 1e-3  # drivers publish unit quaternions to float precision
DEFAULT_IMU_TOPIC = "/imu/data"  # the node's (configs/ros2, ros2.topics.IMU) and the simulated bags'
IMU_MAX_AGE_S = 0.1  # the node's default imu_max_age_s: an older sample at a frame is stale


def attitude_from_imu(message: Any, topic: str) -> tuple[float, float]:
    """(roll, pitch) in radians of an `Imu` message's orientation (ValueError naming `topic`)."""
    covariance = np.asarray(message.orientation_covariance, dtype=float).reshape(-1)
    if covariance.size and covariance[0] == -1.0:  # sensor_msgs/Imu: "no orientation estimate"
        raise ValueError(f"{topic}: the IMU gives no orientation (orientation_covariance[0] = -1)")
    q = message.orientation
    x, y, z, w = (float(q.x), float(q.y), float(q.z), float(q.w))
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if not (math.isfinite(norm) and abs(norm - 1.0) <= QUATERNION_NORM_TOLERANCE):
        raise ValueError(f"{topic}: orientation is not a unit quaternion (norm {norm:.4g})")
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    return roll, pitch


@dataclass
class ImuTrack:
    """A recorded IMU's attitudes by stamp; `at(t)` is what the runtime gets at a frame at `t`."""

    topic: str
    stamps: list[float] = field(default_factory=list)  # ascending
    attitudes: list[tuple[float, float]] = field(default_factory=list)
    max_age_s: float = IMU_MAX_AGE_S
    ignored: list[str] = field(default_factory=list)  # why each unusable message was skipped
    stale: int = 0  # frames stepped on level ground: no sample within max_age_s before them

    def add(self, t: float, message: Any) -> None:
        """One `Imu` message stamped `t` (in any order); one the node would ignore is counted."""
        try:
            attitude = attitude_from_imu(message, self.topic)
        except ValueError as exc:
            self.ignored.append(str(exc))
            return
        where = bisect.bisect_right(self.stamps, t)
        self.stamps.insert(where, t)
        self.attitudes.insert(where, attitude)

    def at(self, t: float) -> tuple[float, float] | None:
        """(roll, pitch) of the newest sample at or before `t`, or None (level ground) when it is stale."""
        where = bisect.bisect_right(self.stamps, t) - 1
        if where < 0 or t - self.stamps[where] > self.max_age_s:
            self.stale += 1
            return None
        return self.attitudes[where]

    def notes(self) -> list[str]:
        """What the replay did without the IMU (a stale sample, unusable messages)."""
        lines = []
        if self.ignored:
            lines.append(f"{len(self.ignored)} message(s) of {self.topic} ignored (first: {self.ignored[0]})")
        if self.stale:
            lines.append(
                f"{self.stale} frame(s) had no {self.topic} sample within {self.max_age_s} s before them: "
                "stepped on level ground, as the node does"
            )
        return lines
