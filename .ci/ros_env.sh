#!/usr/bin/env bash
# The rclpy environment of the ROS 2 node tests: a virtual environment of its own, never .venv.
#
# The community wheels of ROS 2 Kilted (`ros-rclpy[fastrtps]` and message packages) come with
# `ros-wheels-bootstrapper`, whose .pth file restarts every Python process of the environment
# with LD_LIBRARY_PATH set: it must not touch the training environment. segmin goes in without
# its dependencies (the robot runtime's numpy, OpenCV, onnxruntime, ai-edge-litert (the [litert]
# extra: a shipped model name runs its INT8 LiteRT file) and PyYAML are installed explicitly, with rosbags for the test's bag player, foxglove-sdk for the live view (live_port) and
# websockets for the test's live-view client):
# no torch, pybullet or matplotlib.
# The package ros/segmin_ros is built here as a robot team builds it: colcon (colcon-common-extensions,
# which brings colcon-ros for package.xml packages) with ament_package (reads package.xml) and
# ament_index_python (the launch file finds the installed parameter file with it). The launch
# system itself (launch, launch_ros) has no wheel in the registry: the tests read the launch file
# with stand-ins of its few classes.
#
# Usage: bash .ci/ros_env.sh [FOLDER]   (default .ros-venv). A folder built by this same script
# is kept (CI keeps it outside the clone, so it is built once per machine); only segmin is
# re-installed into it, editable, from this checkout.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
ROSENV=${1:-.ros-venv}
stamp="$ROSENV/.segmin-stamp"
want=$(sha256sum .ci/ros_env.sh | cut -c1-16)
start=$(date +%s)
quiet() { grep -v -e "^WARNING: Location" -e "^\[notice\]" -e "BuildBackendWarning" -e "^ *!!" -e "^ *\*\*\*" \
    -e "Please be careful" -e "name as your package" -e "with strategy" -e "^ *$" || true; }
if [[ -f "$stamp" && "$(cat "$stamp")" == "$want" ]]; then
    echo "ros env: $ROSENV kept"
else
    rm -rf "$ROSENV"
    "$PYTHON" -m venv "$ROSENV"
    "$ROSENV/bin/python" -m pip install --quiet --upgrade pip 2>&1 | quiet
    "$ROSENV/bin/python" -m pip install --quiet \
        'ros-rclpy[fastrtps]==9.1.2' 'ros-sensor-msgs==5.5.1' 'ros-geometry-msgs==5.5.1' 'ros-std-msgs==5.5.1' \
        'ros-std-srvs==5.5.1' 'ros-diagnostic-msgs==5.5.1' \
        'colcon-common-extensions==0.3.0' 'ros-ament-package==0.17.2' 'ros-ament-index-python==1.11.0' \
        'numpy>=1.24' 'opencv-python-headless>=4.8' 'onnxruntime>=1.17' 'ai-edge-litert>=2.3,<2.4' 'pyyaml>=6.0' 'rosbags>=0.11,<0.12' \
        'foxglove-sdk>=0.30,<0.31' 'websockets>=13' 2>&1 | quiet
    echo "$want" > "$stamp"
fi
"$ROSENV/bin/python" -m pip install --quiet --no-deps -e . 2>&1 | quiet
echo "ros env: $ROSENV ready in $(($(date +%s) - start)) s"
