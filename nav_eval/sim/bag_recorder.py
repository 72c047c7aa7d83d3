"""One simulated run written as a rosbag2 in MCAP: what the robot's camera, IMU and driver would
have recorded, in standard messages and frames, so that Foxglove or RViz shows the run, a team
can test its own ROS stack against segmin's worlds, and `segmin replay --bag` replays it.

Every camera frame (camera_hz) is written, also those the run did not render because the
runtime would not segment them: the recorder renders those itself (`RowEnv.render`) with a
depth-noise generator of its own, so the run's frames, noise and commands are unchanged.

| topic | type | frame | what |
| --- | --- | --- | --- |
| /camera/color/image_raw | sensor_msgs/Image rgb8 | camera_color_optical_frame | the frame |
| /camera/aligned_depth_to_color/image_raw | sensor_msgs/Image 32FC1 | same | metres, 0 = no reading: the float32 the runtime read, exactly |
| .../camera_info (both) | sensor_msgs/CameraInfo | same | pinhole intrinsics, no distortion |
| /imu/data | sensor_msgs/Imu | imu_link | attitude (ENU), yaw rate, gravity's specific force |
| /odom | nav_msgs/Odometry | odom -> base_link | pose from the start pose; exact (the simulator has no odometry drift) |
| /ground_truth/odom | nav_msgs/Odometry | map -> base_link | the true pose |
| /cmd_vel | geometry_msgs/Twist | | each command the runtime computed, at its time |
| /tf, /tf_static | tf2_msgs/TFMessage | | odom -> base_link per frame; map -> odom, base_link -> camera_link -> optical frame, base_link -> imu_link once |
| /segmin/overlay, /segmin/histogram, /segmin/rows, /segmin/path | | | the live view's topics (`live.view`), per runtime step (`step`) |

Stamps are simulated time from 0 s, header stamp = log time. The bag's metadata (custom_data)
holds the field, method, model, seed, depth threshold and rates of the run. The bag is written
inside `<path>.partial/` and moved to `path` when complete, so a folder at `path` is always a whole run.

With `live_port` the same messages, serialised once, also stream to a live view (`live.server`,
`segmin nav-eval --live`); `path` None then writes no bag.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.outputs import check_writable
from segmin.nav_eval.live.view import VIEW_TYPES, ViewMessages, header, image_message, nanoseconds, twist
from segmin.nav_eval.ros2 import topics
from segmin.nav_eval.sim.robot import RobotState, body_axes

GRAVITY = 9.80665
# camera_link (x forward, y left, z up) -> optical frame (x right, y down, z forward), as (x, y, z, w).
OPTICAL_ROTATION = (-0.5, 0.5, -0.5, 0.5)
CAMERA_TYPES = {
    topics.COLOUR: "sensor_msgs/msg/Image",
    topics.COLOUR_INFO: "sensor_msgs/msg/CameraInfo",
    topics.DEPTH: "sensor_msgs/msg/Image",
    topics.DEPTH_INFO: "sensor_msgs/msg/CameraInfo",
}
TOPIC_TYPES = {
    **CAMERA_TYPES,
    topics.IMU: "sensor_msgs/msg/Imu",
    topics.ODOM: "nav_msgs/msg/Odometry",
    topics.GROUND_TRUTH: "nav_msgs/msg/Odometry",
    topics.CMD_VEL: "geometry_msgs/msg/Twist",
    topics.TF: "tf2_msgs/msg/TFMessage",
    topics.TF_STATIC: "tf2_msgs/msg/TFMessage",
    **VIEW_TYPES,
}


def partial_path(path: Path) -> Path:
    """The folder a bag at `path` is written in until it is complete."""
    return path.with_name(path.name + ".partial")


def check_bag_path(path: Path) -> None:
    """ValueError naming what is in the way of a bag at `path`, for a check before any run: its
    folder not writable (read-only, a file there), or a file or symbolic link at `path` or at its
    partial folder, which the recorder only replaces when it is a bag folder (found after the run)."""
    check_writable(path.parent, "bag folder")
    for where in (path, partial_path(path)):
        if where.is_symlink() or (where.exists() and not where.is_dir()):
            kind = "a symbolic link" if where.is_symlink() else "a file"
            raise ValueError(f"{where}: {kind} where a run's bag goes (only a bag folder is replaced); remove it")


def quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a 3 x 3 rotation matrix (Shepperd's method: stable for every angle)."""
    r = np.asarray(rotation, dtype=float)
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = ((r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s)
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = (0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s)
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = ((r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = ((r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s, (r[1, 0] - r[0, 1]) / s)
    x, y, z, w = q
    return float(x), float(y), float(z), float(w)


def _yaw_matrix(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def base_pose(state: RobotState) -> np.ndarray:
    """4 x 4 map -> base_link of the robot: on the terrain, its axes those the camera rides on."""
    pose = np.eye(4)
    pose[:3, :3] = _yaw_matrix(state.yaw) @ np.column_stack(body_axes(state))
    pose[:3, 3] = (state.x, state.y, state.z)
    return pose


class RunRecorder:
    """Writes one run (see the module docstring); `frame` per camera frame, `step` per runtime
    step, `command` per command.

    Use as a context manager: an exception inside leaves no bag (the partial folder is removed).
    """

    def __init__(
        self,
        path: str | Path | None,
        camera: Any,
        seed: int,
        metadata: dict[str, str] | None = None,
        live_port: int = 0,
    ) -> None:
        from rosbags.typesys import Stores, get_typestore

        self._store = get_typestore(Stores.ROS2_HUMBLE)
        self._types = self._store.types
        self.camera = camera
        self._noise_rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x0BA6]))
        self._view = ViewMessages(self._types)
        self._last_rgb: np.ndarray | None = None  # the newest frame's image and odometry pose, for `step`
        self._last_pose: Any = None
        self._odom_origin: np.ndarray | None = None  # 4 x 4 map -> odom: the start pose, level
        self.frames = 0
        self.commands = 0
        self.path = None if path is None else Path(path)
        self._live: Any = None
        if live_port:
            from segmin.nav_eval.live.server import LiveServer

            self._live = LiveServer(TOPIC_TYPES, live_port)
        self._writer: Any = None
        if self.path is not None:
            self._open_bag(self.path, metadata or {})

    def _open_bag(self, path: Path, metadata: dict[str, str]) -> None:
        """Start the bag inside <path>.partial/, under the bag's own name (rosbag2 names its file after it)."""
        from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
        from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

        self._partial = partial_path(path)
        shutil.rmtree(self._partial, ignore_errors=True)
        self._partial.mkdir(parents=True)
        self._writer = Writer(self._partial / path.name, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for key, value in metadata.items():
            self._writer.set_custom_data(f"segmin.{key}", str(value))
        self._writer.open()
        never = QosTime(0, 0)
        latched = Qos(
            QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
            never, never, QosLiveliness.AUTOMATIC, never, False,
        )  # fmt: skip
        self._connections = {
            topic: self._writer.add_connection(
                topic,
                msgtype,
                typestore=self._store,
                offered_qos_profiles=[latched] if topic == topics.TF_STATIC else [],
            )
            for topic, msgtype in TOPIC_TYPES.items()
        }

    # ---- the rollout's calls -------------------------------------------------------------------
    def frame(self, simulator: Any, t: float, rendered: Any | None) -> None:
        """One camera frame of `simulator` (a `RowEnv`) at time `t`: images, camera info, IMU,
        odometry, TF. `rendered` is the run's frame, or None for a frame the run skips (rendered
        here with the recorder's own noise generator, leaving the run's as it is)."""
        frame = rendered if rendered is not None else simulator.render(self._noise_rng)
        rgb, depth = frame.rgb, frame.depth
        state = simulator.robot.state
        pose = base_pose(state)
        if self._odom_origin is None:
            self._odom_origin = np.eye(4)
            self._odom_origin[:3, :3] = _yaw_matrix(state.yaw)
            self._odom_origin[:3, 3] = pose[:3, 3]
            self._write_static(t)
        header = self._header(t, topics.OPTICAL_FRAME)
        self._write(topics.COLOUR, t, self._image(header, np.asarray(rgb, dtype=np.uint8), "rgb8"))
        self._write(topics.DEPTH, t, self._image(header, np.asarray(depth, dtype=np.float32), "32FC1"))
        info_message = self._camera_info(header)
        self._write(topics.COLOUR_INFO, t, info_message)
        self._write(topics.DEPTH_INFO, t, info_message)
        self._write(topics.IMU, t, self._imu(t, pose, state))
        odom = np.linalg.inv(self._odom_origin) @ pose
        odometry = self._odometry(t, topics.ODOM_FRAME, odom, state)
        self._write(topics.ODOM, t, odometry)
        self._last_rgb, self._last_pose = np.asarray(rgb, dtype=np.uint8), odometry.pose.pose
        self._write(topics.GROUND_TRUTH, t, self._odometry(t, topics.MAP_FRAME, pose, state))
        tf = self._types["tf2_msgs/msg/TFMessage"](
            transforms=[self._transform(t, topics.ODOM_FRAME, topics.BASE_FRAME, odom)]
        )
        self._write(topics.TF, t, tf)
        self.frames += 1

    def step(self, t: float, output: Any, navigator: Any) -> None:
        """The live view's topics of the runtime's step at `t` (a `FollowerOutput` of `navigator`),
        drawn on the newest frame `frame` wrote."""
        for topic, message in self._view.step(t, self._last_rgb, output, navigator, self._last_pose):
            self._write(topic, t, message)

    def command(self, t: float, v: float, omega: float) -> None:
        """A command the runtime computed at time `t`."""
        self._write(topics.CMD_VEL, t, twist(self._types, v, omega))
        self.commands += 1

    def close(self) -> Path | None:
        """Finish the bag and move it to `path` (replacing an older one); returns `path` (None
        without a bag). Stops the live view."""
        if self._live is not None:
            self._live.close()
        if self.path is None:
            return None
        self._writer.close()
        if self.path.exists():
            shutil.rmtree(self.path)
        (self._partial / self.path.name).rename(self.path)
        self._partial.rmdir()
        return self.path

    def abort(self) -> None:
        """Drop the unfinished bag; stop the live view."""
        if self._live is not None:
            self._live.close()
        if self.path is None:
            return
        try:
            self._writer.close()
        finally:
            shutil.rmtree(self._partial, ignore_errors=True)

    def __enter__(self) -> RunRecorder:
        return self

    def __exit__(self, kind: object, *rest: object) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()

    # ---- messages ------------------------------------------------------------------------------
    def _write(self, topic: str, t: float, message: Any) -> None:
        data = self._store.serialize_cdr(message, TOPIC_TYPES[topic])
        if self._writer is not None:
            self._writer.write(self._connections[topic], nanoseconds(t), data)
        if self._live is not None:
            self._live.log(topic, t, data)

    def _header(self, t: float, frame_id: str) -> Any:
        return header(self._types, t, frame_id)

    def _image(self, head: Any, pixels: np.ndarray, encoding: str) -> Any:
        return image_message(self._types, head, pixels, encoding)

    def _camera_info(self, header: Any) -> Any:
        k = self.camera.intrinsics()
        fx, fy, cx, cy = k["fx"], k["fy"], k["cx"], k["cy"]
        roi = self._types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        return self._types["sensor_msgs/msg/CameraInfo"](
            header=header,
            height=int(k["height"]),
            width=int(k["width"]),
            distortion_model="plumb_bob",
            d=np.zeros(5),
            k=np.array([fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]),
            r=np.eye(3).reshape(-1),
            p=np.array([fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]),
            binning_x=0,
            binning_y=0,
            roi=roi,
        )

    def _imu(self, t: float, pose: np.ndarray, state: RobotState) -> Any:
        vector = self._types["geometry_msgs/msg/Vector3"]
        gravity = pose[:3, :3].T @ np.array([0.0, 0.0, GRAVITY])  # what an accelerometer at rest reads
        return self._types["sensor_msgs/msg/Imu"](
            header=self._header(t, topics.IMU_FRAME),
            orientation=self._quaternion(quaternion(pose[:3, :3])),
            orientation_covariance=np.zeros(9),
            angular_velocity=vector(x=0.0, y=0.0, z=float(state.omega)),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=vector(x=float(gravity[0]), y=float(gravity[1]), z=float(gravity[2])),
            linear_acceleration_covariance=np.zeros(9),
        )

    def _odometry(self, t: float, frame: str, pose: np.ndarray, state: RobotState) -> Any:
        types = self._types
        vector = types["geometry_msgs/msg/Vector3"]
        point = types["geometry_msgs/msg/Point"](x=float(pose[0, 3]), y=float(pose[1, 3]), z=float(pose[2, 3]))
        return types["nav_msgs/msg/Odometry"](
            header=self._header(t, frame),
            child_frame_id=topics.BASE_FRAME,
            pose=types["geometry_msgs/msg/PoseWithCovariance"](
                pose=types["geometry_msgs/msg/Pose"](
                    position=point, orientation=self._quaternion(quaternion(pose[:3, :3]))
                ),
                covariance=np.zeros(36),
            ),
            twist=types["geometry_msgs/msg/TwistWithCovariance"](
                twist=types["geometry_msgs/msg/Twist"](
                    linear=vector(x=float(state.v), y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=float(state.omega))
                ),
                covariance=np.zeros(36),
            ),
        )

    def _quaternion(self, q: tuple[float, float, float, float]) -> Any:
        return self._types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])

    def _transform(self, t: float, parent: str, child: str, pose: np.ndarray) -> Any:
        types = self._types
        translation = types["geometry_msgs/msg/Vector3"](x=float(pose[0, 3]), y=float(pose[1, 3]), z=float(pose[2, 3]))
        return types["geometry_msgs/msg/TransformStamped"](
            header=self._header(t, parent),
            child_frame_id=child,
            transform=types["geometry_msgs/msg/Transform"](
                translation=translation, rotation=self._quaternion(quaternion(pose[:3, :3]))
            ),
        )

    def _write_static(self, t: float) -> None:
        """map -> odom (the start pose), base_link -> camera_link (the mount, tilted up by tilt_deg as
        the renderer and the runtime's camera model tilt it) -> optical frame, base_link -> imu_link
        (at the base)."""
        assert self._odom_origin is not None
        mount = np.eye(4)
        tilt = -math.radians(float(self.camera.tilt_deg))  # REP 103 pitch lowers the nose; tilt_deg raises it
        mount[:3, :3] = [[math.cos(tilt), 0.0, math.sin(tilt)], [0.0, 1.0, 0.0], [-math.sin(tilt), 0.0, math.cos(tilt)]]
        mount[:3, 3] = (float(self.camera.mount_forward), 0.0, float(self.camera.mount_height))
        optical = self._transform(t, topics.CAMERA_FRAME, topics.OPTICAL_FRAME, np.eye(4))
        optical.transform.rotation = self._quaternion(OPTICAL_ROTATION)
        transforms = [
            self._transform(t, topics.MAP_FRAME, topics.ODOM_FRAME, self._odom_origin),
            self._transform(t, topics.BASE_FRAME, topics.CAMERA_FRAME, mount),
            optical,
            self._transform(t, topics.BASE_FRAME, topics.IMU_FRAME, np.eye(4)),
        ]
        self._write(topics.TF_STATIC, t, self._types["tf2_msgs/msg/TFMessage"](transforms=transforms))
