"""`segmin bench ros2`: the row-follower node fed colour + depth from a bag at 30 Hz, measured.

Run it where rclpy is importable (the ROS environment of .ci/ros_env.sh, or a sourced ROS 2),
inside a network namespace holding only loopback: it starts DDS and refuses otherwise.

- The runtime's own step: `FollowerCore` on the same frames in this process, without ROS, at the bag's pace
  (decode, pair, `RowFollower.step`), timed on the frames that gave a command.
- The node (`segmin ros2 follow`, a child process, enabled, TwistStamped) fed the bag's frames
  looped for `seconds`, restamped with the wall clock at publication. Measured by the node
  (`timing.CommandTiming`, read from its diagnostics): latency from the image's reception to the
  command computed from it published, and the command period and its jitter at publication.
  Measured here, at the receiving end: image published to command received (the node's latency
  plus DDS both ways plus this process's executor) and the period at reception. Also the frames
  the node stepped against those published (its queues hold one frame, so they cannot grow;
  frames it could not take are replaced and counted here) and its resident memory each second.
- The load average and the Fast DDS transports (`FASTDDS_BUILTIN_TRANSPORTS`, e.g. SHM; unset:
  the default UDPv4 + shared memory) are printed with the figures.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from segmin.nav_eval.ros2 import topics
from segmin.nav_eval.ros2.params import NODE_NAME, defaults_yaml, flatten

NS = 10**9


def check_confined() -> None:
    """Refuse to start DDS unless this network namespace holds only loopback."""
    import socket

    links = sorted(name for _, name in socket.if_nameindex())  # this process's namespace (/sys may be the host's)
    if links != ["lo"]:
        raise ValueError(
            f"segmin bench ros2 starts DDS: run it in a loopback-only network namespace (this one has {links}), "
            "e.g. unshare -n bash -c 'ip link set lo up; ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST segmin bench ros2 ...'"
        )


def read_frames(bag: Path, colour: str, depth: str) -> list[tuple[int, str, bytes]]:
    """(log time ns, topic, raw CDR) of the colour and depth messages, in bag order."""
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        wanted = [c for c in reader.connections if c.topic in (colour, depth)]
        if {c.topic for c in wanted} != {colour, depth}:
            raise ValueError(f"--bag {bag}: needs {colour} and {depth}; it has {sorted(reader.topics)}")
        return [(t, c.topic, bytes(raw)) for c, t, raw in reader.messages(connections=wanted)]


def runtime_step_s(frames: list[tuple[int, str, bytes]], values: dict[str, Any]) -> np.ndarray:
    """Seconds per frame of FollowerCore (no ROS) on the frames that gave a command, each message
    handed over at its recorded time: onnxruntime run back to back is up to 1.6x faster than at a
    camera's pace (its threads idle between frames), which would flatter the reference."""
    from rosbags.typesys import Stores, get_typestore

    from segmin.nav_eval.ros2.core import FollowerCore
    from segmin.nav_eval.ros2.node import load_segmenter
    from segmin.nav_eval.ros2.params import node_params

    store = get_typestore(Stores.ROS2_HUMBLE)
    params = node_params({**values, "publish_on_timer": False})  # each fresh command marks a step that gave one
    sent: list[object] = []
    core = FollowerCore(params, load_segmenter(params), sent.append, lambda _: None)
    times = []
    messages = [(t, topic, store.deserialize_cdr(raw, "sensor_msgs/msg/Image")) for t, topic, raw in frames]
    begin = time.monotonic()
    for t, topic, message in messages:
        time.sleep(max(0.0, begin + (t - messages[0][0]) / NS - time.monotonic()))
        before = len(sent)
        start = time.perf_counter()
        (core.on_colour if topic == params.node.colour_topic else core.on_depth)(message, t / NS)
        if len(sent) > before:
            times.append(time.perf_counter() - start)
    return np.asarray(times)


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return math.nan


class _Feeder:
    """Publishes the frames and records the commands (rclpy spun on a thread of its own)."""

    def __init__(self, colour: str, depth: str) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import TwistStamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Image

        rclpy.init()
        self.node = rclpy.create_node("segmin_bench_feeder")
        sensor = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.pub = {topic: self.node.create_publisher(Image, topic, sensor) for topic in (colour, depth)}
        self.received: list[tuple[float, int]] = []  # (wall s, stamp ns)
        self.diagnostics: dict[str, str] = {}
        self.node.create_subscription(TwistStamped, topics.CMD_VEL, self._on_cmd, 100)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self.executor.spin, daemon=True)
        self._thread.start()

    def _on_cmd(self, message: Any) -> None:
        self.received.append((time.time(), message.header.stamp.sec * NS + message.header.stamp.nanosec))

    def _on_diagnostics(self, message: Any) -> None:
        for status in message.status:
            if status.name.startswith(NODE_NAME):
                self.diagnostics = {kv.key: kv.value for kv in status.values}

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown()


def _feed(feeder: _Feeder, frames: list[tuple[int, str, bytes]], seconds: float, pid: int) -> tuple[set[int], list]:
    """Publish the frames (looped, restamped with the wall clock) for `seconds`; (stamps, RSS samples)."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Image

    by_t: dict[int, list[tuple[str, bytes]]] = {}
    for t, topic, raw in frames:
        by_t.setdefault(t, []).append((topic, raw))
    pairs = [by_t[t] for t in sorted(by_t)]
    messages = [[(topic, deserialize_message(raw, Image)) for topic, raw in pair] for pair in pairs]
    period = 1.0 / 30
    start = time.monotonic()
    stamps, rss, i = set(), [], 0
    while time.monotonic() - start < seconds:
        time.sleep(max(0.0, start + i * period - time.monotonic()))
        stamp = time.time_ns()
        for topic, message in messages[i % len(messages)]:
            message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, NS)
            feeder.pub[topic].publish(message)
        stamps.add(stamp)
        if i % 30 == 0:
            rss.append((time.monotonic() - start, _rss_mb(pid)))
        i += 1
    return stamps, rss


def bench_ros2(
    model: Path,
    bag: Path,
    seconds: float,
    threads: int,
    method: str,
    depth_threshold: float,
    on_timer: bool = False,
    priority: int = 0,
    spin: bool = False,
) -> str:
    """Run the bench (see the module docstring); returns the report lines. `on_timer`: the node
    publishes from its timer only (`publish_on_timer`); the period is then that of every message."""
    import yaml

    check_confined()
    colour, depth = topics.COLOUR, topics.DEPTH
    frames = read_frames(bag, colour, depth)
    # The node reads a relative model path from its parameter file's (temporary) folder: give it whole.
    model_value = str(Path(model).resolve()) if Path(model).is_file() else str(model)  # or a shipped name
    values = {"model": model_value, "threads": threads, "enabled": True, "twist_stamped": True}
    values |= {"colour_topic": colour, "depth_topic": depth}
    values |= {"publish_on_timer": on_timer, "command_priority": priority, "inference_spin": spin}
    follower = {"method": method, "navigator": {"depth_threshold": depth_threshold}}
    own = runtime_step_s(frames, {**values, **flatten({"follower": follower})})
    with tempfile.TemporaryDirectory() as folder:
        params = Path(folder) / "params.yaml"
        text = yaml.safe_load(defaults_yaml(method=method))
        text[NODE_NAME]["ros__parameters"].update(values)
        text[NODE_NAME]["ros__parameters"]["follower"]["navigator"]["depth_threshold"] = depth_threshold
        params.write_text(yaml.safe_dump(text))
        node = subprocess.Popen([sys.executable, "-m", "segmin.app.cli", "ros2", "follow", "--params", str(params)])
        feeder = _Feeder(colour, depth)
        try:
            time.sleep(5.0)  # the node loads its model and discovers the feeder
            stamps, rss = _feed(feeder, frames, seconds, node.pid)
            time.sleep(1.5)
        finally:
            node.send_signal(2)
            node.wait(timeout=20)
            feeder.close()
    first: dict[int, float] = {}
    for wall, stamp in feeder.received:
        if stamp in stamps and stamp not in first:
            first[stamp] = wall
    if not first:
        raise RuntimeError(
            f"the bench received no command from the node in {seconds:.0f} s (exit code {node.returncode}; "
            "its log is above): nothing to measure"
        )
    latency = np.array([first[s] - s / NS for s in sorted(first)])
    sent = [wall for wall, stamp in feeder.received if stamp in stamps] if on_timer else sorted(first.values())
    periods = np.diff(sent)
    jitter = np.abs(periods - 0.2) if periods.size else np.zeros(1)
    after = [m for t, m in rss if t >= 10.0]
    node_side = feeder.diagnostics
    own_p95 = 1e3 * np.percentile(own, 95)
    node_p95 = node_side.get("latency image received to command published p95 ms", "-")
    ratio = f"{float(node_p95) / own_p95:.2f}" if node_p95 != "-" else "-"
    lines = [
        f"segmin bench ros2: {method}, {Path(model).name}, {len(frames) // 2} frames looped for {seconds:.0f} s at 30 Hz, "
        f"commands {'from the timer' if on_timer else 'at once'}, command thread "
        f"{f'SCHED_FIFO {priority}' if priority else 'at normal priority'}, inference "
        f"{'spinning' if spin else 'without busy-wait'}; load {' '.join(f'{x:.2f}' for x in os.getloadavg())}; "
        f"FASTDDS_BUILTIN_TRANSPORTS={os.environ.get('FASTDDS_BUILTIN_TRANSPORTS', '(default)')}",
        f"runtime's own step (FollowerCore, no ROS, at the bag's pace, frames giving a command): median {1e3 * np.median(own):.1f} ms, "
        f"p95 {own_p95:.1f} ms ({own.size} steps)",
        "node, measured by the node: image received -> command published median "
        f"{node_side.get('latency image received to command published median ms', '-')} ms, p95 {node_p95} ms "
        f"= {ratio} x the runtime's own step p95 (target <= 1.5); command period median "
        f"{node_side.get('command period median ms', '-')} ms, jitter p99 "
        f"{node_side.get('command period jitter p99 ms', '-')} ms (target <= 5 ms at 5 Hz; "
        f"{node_side.get('command periods timed', '-')} periods)",
        f"at this receiver: image published -> command received median {1e3 * np.median(latency):.1f} ms, "
        f"p95 {1e3 * np.percentile(latency, 95):.1f} ms ({latency.size} commands); period median "
        f"{1e3 * np.median(periods):.1f} ms, jitter p99 {1e3 * np.percentile(jitter, 99):.1f} ms, max {1e3 * jitter.max():.1f} ms",
        f"frames published {len(stamps)}, stepped by the node {node_side.get('frames stepped', '?')}, "
        f"unpaired colour / depth {node_side.get('unpaired colour frames', '?')} / "
        f"{node_side.get('unpaired depth frames', '?')}; latency median first / last 10 s "
        f"{1e3 * np.median(latency[:50]):.1f} / {1e3 * np.median(latency[-50:]):.1f} ms",
        f"node resident memory: {rss[0][1]:.0f} MB at start, "
        + (
            f"{after[0]:.0f} MB at 10 s, {after[-1]:.0f} MB at the end (min {min(after):.0f}, max {max(after):.0f})"
            if after
            else "-"
        ),
    ]
    return "\n".join(lines)
