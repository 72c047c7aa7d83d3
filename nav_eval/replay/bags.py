"""The frames of a ROS bag for `segmin replay --bag`: ROS 1 `.bag` files and rosbag2 folders
(sqlite3 or MCAP), read with `rosbags` (pure Python, no ROS needed; the [ros] extra).

Colour comes from `--rgb-topic` (`Image` or `CompressedImage`), aligned depth from the optional
`--depth-topic`; they are decoded by `replay.ros_images` and paired by header stamp within
`--slop` seconds by `replay.stamp_pairing`, exactly as the ROS 2 node does. The runtime's time
is the colour frame's header stamp (not the time the recorder logged the message).

A topic the bag lacks, holds no message or is of another message type, and one topic given as
both colour and depth, stop the replay before any output with one line listing the bag's topics.
A message that cannot be used (an encoding, 32FC1 depth in millimetres, a colour frame of
another size than the first) stops it at that message, naming the topic, the message's index on
it and its stamp; a bag whose colour and depth never pair within `--slop` stops it naming the
nearest gap between their stamps. Nothing is written then. `rosbags` is imported only here,
when `--bag` is used.

SegCorridor places its pixels with the camera's intrinsics: `bag_camera` reads them from the
bag's first `CameraInfo` on `--camera-info-topic` (by default the colour topic's sibling
`camera_info`, as camera drivers publish it). `bag_imu` reads its IMU (`sensor_msgs/Imu` on
`--imu-topic`, the node's `/imu/data` by default) for SegCorridor's roll and pitch: each frame
takes the newest sample stamped at or before it (`replay.imu`). A bag without the default topic
is replayed on level ground, as before; a topic named with `--imu-topic` that the bag lacks,
holds no message or holds another type stops the replay, naming it. `bag_poses` reads the robot's
odometry for the live view's path (`--live`).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from segmin.nav_eval.replay.imu import ImuTrack
from segmin.nav_eval.replay.ros_images import (
    ImageMessageError,
    camera_from_info,
    decode_colour,
    decode_depth,
    stamp_seconds,
)
from segmin.nav_eval.replay.run import FrameSource
from segmin.nav_eval.replay.stamp_pairing import StampOrderError, StampPairer
from segmin.nav_eval.runtime.camera import CameraGeometry
from segmin.nav_eval.runtime.follower_config import CameraConfig

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
IMU_TYPE = "sensor_msgs/msg/Imu"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
DEFAULT_SLOP_S = 0.01  # RealSense colour and aligned depth differ by a few ms; frames are 33 ms apart


def open_bag(path: Path) -> Any:
    """An open `rosbags` AnyReader on `path` (ValueError naming the path when it is no bag)."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise FileNotFoundError(f"--bag {path}: no such file or folder")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError) as exc:
        raise ValueError(f"--bag {path}: not a ROS 1 .bag file or a rosbag2 folder rosbags can read ({exc})") from None
    return reader


def _topics_line(reader: Any) -> str:
    return ", ".join(f"{name} ({info.msgtype}, {info.msgcount})" for name, info in sorted(reader.topics.items()))


def _message_count(reader: Any, path: Path, topic: str, option: str) -> int:
    """The messages of an image topic (ValueError listing the topics when it is absent, holds
    another type or no message: a replay of it would pair nothing and write nothing useful)."""
    info = reader.topics.get(topic)
    if info is None:
        raise ValueError(f"--bag {path}: no topic {topic!r} ({option}); the bag has: {_topics_line(reader)}")
    if info.msgtype not in IMAGE_TYPES:
        raise ValueError(
            f"--bag {path}: {option} {topic} holds {info.msgtype}, not {' or '.join(IMAGE_TYPES)}; "
            f"the bag has: {_topics_line(reader)}"
        )
    count = sum(c.msgcount for c in reader.connections if c.topic == topic)
    if count == 0:
        raise ValueError(f"--bag {path}: {option} {topic} has no messages; the bag has: {_topics_line(reader)}")
    return count


def camera_info_topic(rgb_topic: str) -> str:
    """The CameraInfo topic a driver publishes beside `rgb_topic` (`/camera/color/image_raw` ->
    `/camera/color/camera_info`; a `/compressed` transport's too)."""
    base = rgb_topic.removesuffix("/compressed").rstrip("/")
    return f"{base.rpartition('/')[0]}/camera_info"


def bag_camera(path: str | Path, topic: str, mount: CameraConfig) -> CameraGeometry:
    """The camera of the bag's first CameraInfo on `topic`, on `mount` (ValueError naming the bag
    and the topic, listing the bag's topics when it has no such one)."""
    path = Path(path)
    reader = open_bag(path)
    try:
        info = reader.topics.get(topic)
        if info is None or info.msgtype != CAMERA_INFO_TYPE:
            what = "no topic" if info is None else f"{info.msgtype}, not {CAMERA_INFO_TYPE}, on"
            raise ValueError(
                f"--bag {path}: {what} {topic!r} (--camera-info-topic, SegCorridor's camera intrinsics); "
                f"the bag has: {_topics_line(reader)}"
            )
        connections = [c for c in reader.connections if c.topic == topic]
        for connection, _, raw in reader.messages(connections=connections):
            return camera_from_info(reader.deserialize(raw, connection.msgtype), topic, mount)
        raise ValueError(f"--bag {path}: --camera-info-topic {topic} has no messages")
    finally:
        reader.close()


def bag_imu(path: str | Path, topic: str, *, named: bool) -> ImuTrack | None:
    """The bag's IMU on `topic`; None when the topic was not `named` (the default) and the bag
    has no message of it (level ground then). ValueError naming the topic when a `named` one is
    absent or empty, and when the topic holds another type."""
    path = Path(path)
    reader = open_bag(path)
    try:
        info = reader.topics.get(topic)
        count = sum(c.msgcount for c in reader.connections if c.topic == topic)
        if info is not None and info.msgtype != IMU_TYPE:
            raise ValueError(
                f"--bag {path}: --imu-topic {topic} holds {info.msgtype}, not {IMU_TYPE}; "
                f"the bag has: {_topics_line(reader)}"
            )
        if count == 0:
            if not named:
                return None
            what = "has no messages" if info is not None else "is not in the bag"
            raise ValueError(f"--bag {path}: --imu-topic {topic} {what}; the bag has: {_topics_line(reader)}")
        track = ImuTrack(topic)
        connections = [c for c in reader.connections if c.topic == topic]
        for connection, _, raw in reader.messages(connections=connections):
            message = reader.deserialize(raw, connection.msgtype)
            track.add(stamp_seconds(message), message)
        return track
    finally:
        reader.close()


def bag_poses(path: str | Path, topic: str) -> list[tuple[float, tuple[float, ...]]]:
    """The robot's poses on the `nav_msgs/Odometry` topic `topic`, ascending by header stamp, as
    (t, (x, y, z, qx, qy, qz, qw)); empty when the bag has no such topic (the live view's path
    and TF then stay out, said by the replay)."""
    reader = open_bag(Path(path))
    try:
        connections = [c for c in reader.connections if c.topic == topic and c.msgtype == ODOMETRY_TYPE]
        poses = []
        for connection, _, raw in reader.messages(connections=connections):
            message = reader.deserialize(raw, connection.msgtype)
            p, q = message.pose.pose.position, message.pose.pose.orientation
            poses.append((stamp_seconds(message), tuple(float(v) for v in (p.x, p.y, p.z, q.x, q.y, q.z, q.w))))
        return sorted(poses, key=lambda pose: pose[0])
    finally:
        reader.close()


def bag_frames(
    path: str | Path, rgb_topic: str, depth_topic: str | None = None, slop: float = DEFAULT_SLOP_S
) -> FrameSource:
    """The bag's frames as a replay `FrameSource` (topics are checked now, frames read lazily)."""
    path = Path(path)
    if not slop >= 0:
        raise ValueError(f"--slop must be a number of seconds >= 0, got {slop!r}")
    if depth_topic == rgb_topic:
        raise ValueError(
            f"--rgb-topic and --depth-topic are both {rgb_topic}: give the colour and the aligned depth topics"
        )
    reader = open_bag(path)
    try:
        count = _message_count(reader, path, rgb_topic, "--rgb-topic")
        if depth_topic is not None:
            _message_count(reader, path, depth_topic, "--depth-topic")
    finally:
        reader.close()
    pairer = StampPairer(slop, max_pending=1 << 30)  # offline: nothing is dropped for being late
    frames = _read(path, rgb_topic, depth_topic, pairer)

    def notes() -> list[str]:
        lines = []
        if pairer.dropped_colour:
            lines.append(
                f"{pairer.dropped_colour} colour frame(s) of {rgb_topic} had no depth within {slop} s: skipped"
            )
        if pairer.dropped_depth:
            lines.append(
                f"{pairer.dropped_depth} depth frame(s) of {depth_topic} had no colour within {slop} s: skipped"
            )
        return lines

    return FrameSource(count=count, frames=frames, has_depth=depth_topic is not None, notes=notes)


def _size(image: np.ndarray) -> str:
    return f"{image.shape[1]}x{image.shape[0]}"


def _nearest_gap(colour: list[float], depth: list[float]) -> float:
    """The smallest |colour stamp - depth stamp| (each list sorted and non-empty)."""
    c, d = np.asarray(colour), np.asarray(depth)
    after = np.searchsorted(d, c).clip(0, len(d) - 1)
    before = (after - 1).clip(0, len(d) - 1)
    return float(np.minimum(np.abs(d[after] - c), np.abs(d[before] - c)).min())


def _read(
    path: Path, rgb_topic: str, depth_topic: str | None, pairer: StampPairer
) -> Iterator[tuple[str, float, np.ndarray, np.ndarray | None, bool]]:
    """The frames, checked message by message: a bad one stops the replay there, naming it (no
    output is written until every frame ran)."""
    reader = open_bag(path)
    try:
        wanted = [c for c in reader.connections if c.topic in (rgb_topic, depth_topic)]
        stamps: dict[str, list[float]] = {rgb_topic: [], str(depth_topic): []}
        first: np.ndarray | None = None
        paired = 0
        for connection, _, raw in reader.messages(connections=wanted):
            message = reader.deserialize(raw, connection.msgtype)
            t = stamp_seconds(message)
            seen = stamps[connection.topic]
            where = f"{connection.topic} message {len(seen)} (stamp {t:.9f} s)"
            seen.append(t)
            try:
                if connection.topic == rgb_topic:
                    name = f"{rgb_topic}#{len(seen) - 1}"
                    image = decode_colour(message, rgb_topic)
                    first = image if first is None else first
                    if image.shape[:2] != first.shape[:2]:  # the runtime and the video need one frame size
                        raise ValueError(
                            f"--bag {path}: {where} is {_size(image)}, the colour frames before it are {_size(first)}"
                        )
                    if depth_topic is None:
                        yield name, t, image, None, False
                        continue
                    pairs = pairer.add_colour(t, (name, image))
                else:
                    pairs = pairer.add_depth(t, decode_depth(message, connection.topic))
            except StampOrderError as exc:
                raise ValueError(f"{connection.topic}: {exc}") from None
            except ImageMessageError as exc:
                raise ImageMessageError(f"{exc} ({where})") from None
            for colour, depth in pairs:
                (name, image), (d, bad) = colour.item, depth.item
                paired += 1
                yield name, colour.t, image, d, bad
        pairer.finish()
        colour_stamps, depth_stamps = stamps[rgb_topic], stamps[str(depth_topic)]
        if depth_topic is not None and paired == 0 and colour_stamps and depth_stamps:
            raise ValueError(
                f"--bag {path}: no colour frame of {rgb_topic} has a depth frame of {depth_topic} within "
                f"--slop {pairer.slop:g} s: their nearest stamps are {_nearest_gap(colour_stamps, depth_stamps):.6g} s "
                "apart (raise --slop, or check that both topics are stamped by one clock)"
            )
    finally:
        reader.close()
