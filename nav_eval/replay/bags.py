"""The frames of a ROS bag for `segmin replay --bag`: ROS 1 `.bag` files and rosbag2 folders
(sqlite3 or MCAP), read with `rosbags` (pure Python, no ROS needed; the [ros] extra).

Colour comes from `--rgb-topic` (`Image` or `CompressedImage`), aligned depth from the optional
`--depth-topic`; they are decoded by `replay.ros_images` and paired by header stamp within
`--slop` seconds by `replay.stamp_pairing`, exactly as the ROS 2 node does. The runtime's time
is the colour frame's header stamp (not the time the recorder logged the message).

A topic the bag lacks, or one of another message type, stops the replay before any output with
one line listing the bag's topics. `rosbags` is imported only here, when `--bag` is used.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from segmin.nav_eval.replay.ros_images import decode_colour, decode_depth, stamp_seconds
from segmin.nav_eval.replay.run import FrameSource
from segmin.nav_eval.replay.stamp_pairing import StampOrderError, StampPairer

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
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


def _connections(reader: Any, path: Path, topic: str, option: str) -> list[Any]:
    """The bag's connections of an image topic (ValueError listing the topics when it is absent)."""
    info = reader.topics.get(topic)
    if info is None:
        raise ValueError(f"--bag {path}: no topic {topic!r} ({option}); the bag has: {_topics_line(reader)}")
    if info.msgtype not in IMAGE_TYPES:
        raise ValueError(
            f"--bag {path}: {option} {topic} holds {info.msgtype}, not {' or '.join(IMAGE_TYPES)}; "
            f"the bag has: {_topics_line(reader)}"
        )
    return [c for c in reader.connections if c.topic == topic]


def bag_frames(
    path: str | Path, rgb_topic: str, depth_topic: str | None = None, slop: float = DEFAULT_SLOP_S
) -> FrameSource:
    """The bag's frames as a replay `FrameSource` (topics are checked now, frames read lazily)."""
    path = Path(path)
    if not slop >= 0:
        raise ValueError(f"--slop must be a number of seconds >= 0, got {slop!r}")
    reader = open_bag(path)
    try:
        count = sum(c.msgcount for c in _connections(reader, path, rgb_topic, "--rgb-topic"))
        if depth_topic is not None:
            _connections(reader, path, depth_topic, "--depth-topic")
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


def _read(
    path: Path, rgb_topic: str, depth_topic: str | None, pairer: StampPairer
) -> Iterator[tuple[str, float, np.ndarray, np.ndarray | None, bool]]:
    reader = open_bag(path)
    try:
        wanted = [c for c in reader.connections if c.topic in (rgb_topic, depth_topic)]
        index = 0
        for connection, _, raw in reader.messages(connections=wanted):
            message = reader.deserialize(raw, connection.msgtype)
            t = stamp_seconds(message)
            try:
                if connection.topic == rgb_topic:
                    name = f"{rgb_topic}#{index}"
                    index += 1
                    image = decode_colour(message, rgb_topic)
                    if depth_topic is None:
                        yield name, t, image, None, False
                        continue
                    pairs = pairer.add_colour(t, (name, image))
                else:
                    pairs = pairer.add_depth(t, decode_depth(message, depth_topic))
            except StampOrderError as exc:
                raise ValueError(f"{connection.topic}: {exc}") from None
            for colour, depth in pairs:
                (name, image), (d, bad) = colour.item, depth.item
                yield name, colour.t, image, d, bad
        pairer.finish()
    finally:
        reader.close()
