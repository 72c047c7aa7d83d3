"""The topic names and frame ids segmin uses on ROS 2: the node's defaults and the simulated bags'.

Camera topics are those of the RealSense ROS 2 driver (colour and depth aligned to it, as the
paper's Jackal with a D435 publishes them); frames follow REP 105 (map -> odom -> base_link)
and the driver's optical frame (REP 103: x right, y down, z forward). Plain names, no ROS import.
"""

from __future__ import annotations

COLOUR = "/camera/color/image_raw"
COLOUR_INFO = "/camera/color/camera_info"
DEPTH = "/camera/aligned_depth_to_color/image_raw"
DEPTH_INFO = "/camera/aligned_depth_to_color/camera_info"
IMU = "/imu/data"
ODOM = "/odom"
GROUND_TRUTH = "/ground_truth/odom"
CMD_VEL = "/cmd_vel"
TF = "/tf"
TF_STATIC = "/tf_static"

MAP_FRAME = "map"
ODOM_FRAME = "odom"
BASE_FRAME = "base_link"
CAMERA_FRAME = "camera_link"
OPTICAL_FRAME = "camera_color_optical_frame"
IMU_FRAME = "imu_link"

# The live view's own topics (nav_eval.live): streamed by `--live` and written to nav-eval's bags
# beside the ones above, so that one Foxglove layout opens both.
OVERLAY = "/segmin/overlay"  # the camera frame with the mask and the target column drawn
HISTOGRAM = "/segmin/histogram"  # the navigator's smoothed column histogram
ROWS = "/segmin/rows"  # SegCorridor's centreline and rows, in base_link
PATH = "/segmin/path"  # the robot's poses in odom
