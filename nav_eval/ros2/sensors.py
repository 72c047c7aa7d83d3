"""What SegCorridor needs besides the images, from ROS messages: camera intrinsics and the IMU's attitude.

`CameraInfo` gives the pinhole intrinsics of the delivered frames (`k`, `width`, `height`); the
camera's mount on the robot (height, tilt, forward offset) is not in it and comes from the
node's parameters. `Imu` gives the orientation quaternion of the IMU in a level frame (REP 103
/ REP 145: x forward, y left, z up); the runtime wants (roll, pitch) of the body-to-level
rotation R_y(pitch) R_x(roll) (positive roll lifts the left side, positive pitch lowers the
nose), which is the quaternion's ZYX decomposition without its yaw. The IMU is taken to be
mounted level with the body (imu_link aligned with base_link, as on the Jackal).

Each bad message is a ValueError starting with its topic (the node logs it and stops the robot,
or ignores the IMU). No ROS import: fields are read by name, so rclpy's and rosbags' messages
both work.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from segmin.nav_eval.replay.ros_images import camera_from_info
from segmin.nav_eval.runtime.camera import CameraGeometry
from segmin.nav_eval.runtime.follower_config import CameraConfig

QUATERNION_NORM_TOLERANCE = 1e-3  # drivers publish unit quaternions to float precision


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


def geometry_from_camera_info(
    message: Any, topic: str, mount_height: float, tilt_deg: float, mount_forward: float
) -> CameraGeometry:
    """The `CameraGeometry` of a `CameraInfo` message with the node's mount (ValueError naming `topic`)."""
    mount = CameraConfig(mount_height=mount_height, tilt_deg=tilt_deg, mount_forward=mount_forward)
    return camera_from_info(message, topic, mount)
