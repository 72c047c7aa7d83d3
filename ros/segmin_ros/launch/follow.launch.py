"""segmin's row follower: `ros2 launch segmin_ros follow.launch.py [params_file:=FILE] [rgb_topic:=...]`.

`params_file` is the robot's parameter file (default: the Jackal / RealSense D435 file this package
installs). The topic arguments remap the node's topics as the shipped file names them (the
RealSense driver's and the Jackal's defaults) to your robot's; a parameter file that names other
topics needs no remapping. Driving stays off until the node's ~/enable service turns it on.

The file goes to the node as `--params` (not launch_ros's `parameters=`): segmin reads and checks
the whole file before rclpy starts, so a bad value refuses to start with one line naming it.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = "segmin_ros"
# launch argument: (the topic as the shipped parameter file names it, what it carries)
REMAPPED_TOPICS = {
    "rgb_topic": ("/camera/color/image_raw", "colour image (sensor_msgs/Image or CompressedImage)"),
    "depth_topic": ("/camera/aligned_depth_to_color/image_raw", "depth aligned to the colour image"),
    "camera_info_topic": ("/camera/color/camera_info", "colour camera intrinsics (SegCorridor only)"),
    "cmd_vel_topic": ("/cmd_vel", "the velocity commands (e.g. /cmd_vel_nav for a twist_mux input)"),
}


def generate_launch_description() -> LaunchDescription:
    jackal = os.path.join(get_package_share_directory(PACKAGE), "config", "jackal_d435.yaml")
    arguments = [
        DeclareLaunchArgument(
            "params_file", default_value=jackal, description="the node's ROS 2 parameter file (segmin ros2 params)"
        )
    ]
    arguments += [
        DeclareLaunchArgument(name, default_value=topic, description=f"{what} (remaps {topic})")
        for name, (topic, what) in REMAPPED_TOPICS.items()
    ]
    follower = Node(
        package=PACKAGE,
        executable="follow",
        output="screen",
        arguments=["--params", LaunchConfiguration("params_file")],
        remappings=[(topic, LaunchConfiguration(name)) for name, (topic, _) in REMAPPED_TOPICS.items()],
    )
    return LaunchDescription([*arguments, follower])
