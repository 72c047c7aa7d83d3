"""The live view's WebSocket server: foxglove-sdk's, with one channel per topic carrying ROS 2
messages in CDR under the schema records a rosbag2 MCAP file holds (name `pkg/msg/Type`,
encoding `ros2msg`, the message definition `rosbags` writes), so that Foxglove shows a live run
exactly as it shows a bag of it, with one layout.

Every channel is advertised when the server starts, so a client sees the whole view at once;
messages go out as the data comes (replay may run faster than real time); a publisher builds
them only while a client subscribes (`subscribed`). foxglove-sdk and rosbags are imported when a
server starts (the [live] extra), never by the robot runtime.
"""

from __future__ import annotations

import socket
from types import TracebackType
from typing import Any

from segmin.nav_eval.live.view import VIEW_TYPES, nanoseconds
from segmin.nav_eval.ros2.topics import CMD_VEL, PATH, TF

DEFAULT_HOST = "127.0.0.1"  # loopback: a viewer on another computer comes through an SSH tunnel
# What a replay's or the node's live view streams: the view topics but the path, and the command;
# `ODOMETRY_TYPES` besides when the robot's odometry is known (a bag's /odom). nav-eval's live view
# streams its whole bag (`sim.bag_recorder.TOPIC_TYPES`).
LIVE_TYPES = {**{k: v for k, v in VIEW_TYPES.items() if k != PATH}, CMD_VEL: "geometry_msgs/msg/Twist"}
ODOMETRY_TYPES = {PATH: VIEW_TYPES[PATH], TF: "tf2_msgs/msg/TFMessage"}


def check_port(port: int, option: str, host: str = DEFAULT_HOST) -> None:
    """ValueError naming `option` and the port when it cannot be served (taken, out of range),
    checked before the long work starts; foxglove-sdk is imported here too, so a missing [live]
    extra is said before the run, not after it."""
    import foxglove  # noqa: F401  (ModuleNotFoundError: the CLI names the [live] extra)

    if isinstance(port, bool) or not isinstance(port, int) or not 0 < port < 65536:
        raise ValueError(f"{option} {port!r}: a TCP port is an integer from 1 to 65535")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        try:
            probe.bind((host, port))
        except OSError:
            raise ValueError(
                f"{option} {port}: {host}:{port} is in use (another live view or bridge?); choose another port"
            ) from None


def schema_text(store: Any, msgtype: str) -> bytes:
    """The message definition of `msgtype` as rosbags' MCAP writer stores it in a schema record."""
    msgdef, _ = store.generate_msgdef(msgtype, ros_version=2)
    return str(msgdef).encode()


class LiveServer:
    """A foxglove-sdk WebSocket server on `host`:`port` with a CDR channel per topic of
    `topic_types` (topic -> ROS 2 type); `write` logs one message. A context manager: it stops
    the server on exit."""

    def __init__(self, topic_types: dict[str, str], port: int, host: str = DEFAULT_HOST) -> None:
        import foxglove
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores.ROS2_HUMBLE)
        self._types = dict(topic_types)
        self._context = foxglove.Context()  # its own: two servers in one process never share channels
        self._channels = {
            topic: foxglove.Channel(
                topic,
                message_encoding="cdr",
                schema=foxglove.Schema(name=msgtype, encoding="ros2msg", data=schema_text(self.store, msgtype)),
                context=self._context,
            )
            for topic, msgtype in self._types.items()
        }
        try:
            self._server = foxglove.start_server(name="segmin", host=host, port=port, context=self._context)
        except RuntimeError as exc:  # foxglove-sdk reports a taken port as a RuntimeError
            raise ValueError(f"live view: cannot serve on {host}:{port}: {exc}") from None
        self.port = int(self._server.port)

    def subscribed(self, topic: str) -> bool:
        """Whether a client subscribes to `topic` now: its message is worth building."""
        return bool(self._channels[topic].has_sinks())

    def write(self, topic: str, t: float, message: Any) -> None:
        """Log `message` on `topic` at `t` seconds."""
        self._channels[topic].log(bytes(self.store.serialize_cdr(message, self._types[topic])), log_time=nanoseconds(t))

    def log(self, topic: str, t: float, data: bytes) -> None:
        """Log an already serialised message (a bag recorder's) on `topic` at `t` seconds."""
        self._channels[topic].log(bytes(data), log_time=nanoseconds(t))

    def close(self) -> None:
        """Stop the server and close its channels."""
        self._server.stop()
        for channel in self._channels.values():
            channel.close()

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.close()
