"""What SegCorridor needs besides the images, from ROS messages: camera intrinsics and the IMU's attitude.

`CameraInfo` gives the pinhole intrinsics of the delivered frames (`k`, `width`, `height`); the
camera's mount on the robot (height, tilt, forward offset) is not in it and comes from the
node's parameters. `Imu` gives the roll and pitch of the body (`attitude_from_imu`, which lives
in `replay.imu` so that bag replay and the node decode the IMU alike).

Each bad message is a ValueError starting with its topic (the node logs it and stops the robot,
or ignores the IMU). No ROS import: fields are read by name, so rclpy's and rosbags' messages
both work.
"""

from __future__ import annotations

from typing import Any

from segmin.nav_eval.replay.imu import attitude_from_imu
from segmin.nav_eval.replay.ros_images import camera_from_info
from segmin.nav_eval.runtime.camera import CameraGeometry
from segmin.nav_eval.runtime.follower_config import CameraConfig

__all__ = ["attitude_from_imu", "geometry_from_camera_info"]


def geometry_from_camera_info(
    message: Any, topic: str, mount_height: float, tilt_deg: float, mount_forward: float
) -> CameraGeometry:
    """The `CameraGeometry` of a `CameraInfo` message with the node's mount (ValueError naming `topic`)."""
    mount = CameraConfig(mount_height=mount_height, tilt_deg=tilt_deg, mount_forward=mount_forward)
    return camera_from_info(message, topic, mount)
