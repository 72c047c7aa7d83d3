"""Tiny ROS bags written with `rosbags` for the replay tests: images as ROS messages, any storage.

`image_message` / `depth_message` build the rosbags message objects of one frame in a chosen
encoding; `write_bag` writes (topic, stamp, message) triples as a ROS 1 bag or a rosbag2 folder
(sqlite3 or MCAP), serialising with the matching type store.
"""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np
from rosbags.typesys import Stores, get_typestore

ROS2 = get_typestore(Stores.ROS2_HUMBLE)
ROS1 = get_typestore(Stores.ROS1_NOETIC)
IMAGE = "sensor_msgs/msg/Image"


def _header(store, t: float, frame_id: str = "camera_color_optical_frame"):
    ns = round(t * 1e9)
    stamp = store.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    fields = {"stamp": stamp, "frame_id": frame_id}
    if "seq" in store.types["std_msgs/msg/Header"].__dataclass_fields__:
        fields["seq"] = 0
    return store.types["std_msgs/msg/Header"](**fields)


def _image(store, t: float, pixels: np.ndarray, encoding: str, pad: int = 0):
    pixels = np.ascontiguousarray(pixels)
    height, width = pixels.shape[:2]
    row = pixels.reshape(height, -1).view(np.uint8)
    if pad:
        row = np.concatenate([row, np.zeros((height, pad), np.uint8)], axis=1)
    return store.types["sensor_msgs/msg/Image"](
        header=_header(store, t),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=row.shape[1],
        data=np.ascontiguousarray(row).reshape(-1),
    )


def _compressed(store, t: float, data: bytes, fmt: str):
    return store.types["sensor_msgs/msg/CompressedImage"](
        header=_header(store, t), format=fmt, data=np.frombuffer(data, np.uint8).copy()
    )


def image_message(rgb: np.ndarray, t: float, encoding: str, store=ROS2, pad: int = 0):
    """A colour message of RGB pixels: rgb8 / bgr8 / rgba8 / bgra8 Image, or 'png' / 'jpeg' CompressedImage."""
    if encoding in ("png", "jpeg"):
        ok, data = cv2.imencode(f".{'jpg' if encoding == 'jpeg' else 'png'}", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        assert ok
        return _compressed(store, t, data.tobytes(), encoding)
    conversions = {"rgb8": None, "bgr8": cv2.COLOR_RGB2BGR, "rgba8": cv2.COLOR_RGB2RGBA, "bgra8": cv2.COLOR_RGB2BGRA}
    conversion = conversions.get(encoding)
    pixels = rgb if conversion is None else cv2.cvtColor(rgb, conversion)
    return _image(store, t, pixels, encoding, pad)


def depth_message(depth_mm: np.ndarray, t: float, encoding: str, store=ROS2):
    """A depth message of uint16 millimetres: 16UC1 / 32FC1 (metres) Image, 'png' or 'compressedDepth' CompressedImage."""
    if encoding == "16UC1":
        return _image(store, t, depth_mm.astype(np.uint16), "16UC1")
    if encoding == "32FC1":
        return _image(store, t, depth_mm.astype(np.float32) * np.float32(0.001), "32FC1")
    ok, png = cv2.imencode(".png", depth_mm.astype(np.uint16))
    assert ok
    if encoding == "png":
        return _compressed(store, t, png.tobytes(), "16UC1; png")
    header = struct.pack("<iff", 0, 0.0, 0.0)
    return _compressed(store, t, header + png.tobytes(), "16UC1; compressedDepth png")


def write_bag(
    path: Path, messages: list[tuple[str, float, object]], storage: str = "mcap", empty: tuple[str, ...] = ()
) -> Path:
    """Write (topic, log time s, message) as `storage`: 'ros1' (path.bag), 'sqlite3' or 'mcap' (a folder);
    the `empty` topics are declared as `Image` topics with no message."""
    if storage == "ros1":
        from rosbags.rosbag1 import Writer as Writer1

        path = path.with_suffix(".bag")
        with Writer1(path) as writer:
            connections = {topic: writer.add_connection(topic, IMAGE, typestore=ROS1) for topic in empty}
            for topic, t, message in messages:
                if topic not in connections:
                    connections[topic] = writer.add_connection(topic, message.__msgtype__, typestore=ROS1)
                writer.write(connections[topic], round(t * 1e9), ROS1.serialize_ros1(message, message.__msgtype__))
        return path
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        connections = {topic: writer.add_connection(topic, IMAGE, typestore=ROS2) for topic in empty}
        for topic, t, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, message.__msgtype__, typestore=ROS2)
            writer.write(connections[topic], round(t * 1e9), ROS2.serialize_cdr(message, message.__msgtype__))
    return path
