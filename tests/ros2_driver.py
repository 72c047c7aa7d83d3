"""Drives the row-follower node under a real rclpy; run by test_ros2_node.py in the ROS environment.

Usage (inside a network namespace holding only loopback, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST):

    ROSENV/bin/python tests/ros2_driver.py BAG PARAMS OUT.json [NODE_COMMAND.json]

The node runs with `publish_frame_acks`: the player publishes each image message at its recorded
time (or later) and waits for the node's acknowledgement before the next, so the node takes every
frame in the bag's order, whatever the machine's load and DDS's delivery times, as the simulator
did; /clock follows the bag's stamps.

Starts `segmin ros2 follow --params PARAMS` as a child process (use_sim_time: this script owns
/clock), then, in phases, with colour + depth from BAG (a simulated run, restamped by an
offset so that each phase's stamps come after the last):

1. disabled: the bag's first second of frames -> the node must publish nothing;
2. ~/enable true; the whole bag, frame by frame -> TwistStamped commands (stamped with the
   image that gave them) to compare with the bag's /cmd_vel;
3. stall: no frames, the clock runs on -> the watchdog stops the robot after frame_timeout_s;
4. good frames, one colour frame with a wrong encoding, good frames -> an immediate stop, and
   commands again after it (the node alive);
5. a bad parameter (follower.navigator.v_max = -1) -> refused with its reason, the node alive;
6. ~/enable false -> one stop, then silence.

With `live_port` set in PARAMS, a Foxglove client (benchmarks/live_client.py) connects to the
node's live view before phase 1 and records what it streams until the end of phase 2 (`live`).

With NODE_COMMAND.json (a JSON list: the command that starts the node, as the ROS 2 package's
launch file describes it), the node is started that way instead, and only phases 1 and 2 run: the
package's tests compare its commands; the other phases are the node's own.

Writes what it saw as JSON; the test asserts on it. rclpy is imported only here, never by pytest.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import rclpy
import yaml
from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosbags.highlevel import AnyReader
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image
from std_msgs.msg import Header
from std_srvs.srv import SetBool

COLOUR, DEPTH = "/camera/color/image_raw", "/camera/aligned_depth_to_color/image_raw"
NODE = "segmin_row_follower"
NS = 10**9
ACK_TIMEOUT_S = 30.0  # the node takes milliseconds per frame; this long without an acknowledgement is a fault


def read_bag(path: Path) -> tuple[list[tuple[int, str, bytes]], list[tuple[int, float, float]]]:
    frames, commands = [], []
    with AnyReader([path]) as reader:
        for connection, t, raw in reader.messages():
            if connection.topic in (COLOUR, DEPTH):
                frames.append((t, connection.topic, bytes(raw)))
            elif connection.topic == "/cmd_vel":
                twist = reader.deserialize(raw, connection.msgtype)
                commands.append((t, twist.linear.x, twist.angular.z))
    return frames, commands


class Driver(Node):
    def __init__(self) -> None:
        super().__init__("segmin_test_driver")
        sensor = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.pub = {
            COLOUR: self.create_publisher(Image, COLOUR, sensor),
            DEPTH: self.create_publisher(Image, DEPTH, sensor),
        }
        self.clock_pub = self.create_publisher(Clock, "/clock", 10)
        self.received: list[tuple[float, int, float, float]] = []  # (wall, stamp ns, v, omega)
        self.create_subscription(TwistStamped, "/cmd_vel", self._on_cmd, 100)
        self.sent: Counter[int] = Counter()  # stamp (ns) -> image messages published with it
        self.acked: Counter[int] = Counter()  # stamp (ns) -> image messages the node acknowledged
        self.create_subscription(Header, f"/{NODE}/frame_acks", self._on_ack, 100)
        self.enable = self.create_client(SetBool, f"/{NODE}/enable")
        self.set_params = self.create_client(SetParameters, f"/{NODE}/set_parameters")
        self.clock_ns = 1000 * NS

    def _on_cmd(self, message: TwistStamped) -> None:
        stamp = message.header.stamp.sec * NS + message.header.stamp.nanosec
        self.received.append((time.monotonic(), stamp, message.twist.linear.x, message.twist.angular.z))

    def _on_ack(self, header: Header) -> None:
        self.acked[header.stamp.sec * NS + header.stamp.nanosec] += 1

    def wait_for_ack(self, stamp: int) -> None:
        """Spin until the node acknowledged every message stamped `stamp` (RuntimeError after ACK_TIMEOUT_S)."""
        end = time.monotonic() + ACK_TIMEOUT_S
        while self.acked[stamp] < self.sent[stamp]:
            if time.monotonic() > end:
                raise RuntimeError(f"the node acknowledged no image stamped {stamp} ns within {ACK_TIMEOUT_S} s")
            rclpy.spin_once(self, timeout_sec=0.002)

    def spin_for(self, seconds: float, clock_advance: bool = True) -> None:
        """Spin, advancing /clock with the wall clock (100 Hz)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if clock_advance:
                self.set_clock(self.clock_ns + 10_000_000)
            rclpy.spin_once(self, timeout_sec=0.01)

    def set_clock(self, ns: int) -> None:
        self.clock_ns = max(self.clock_ns, ns)
        clock = Clock()
        clock.clock.sec, clock.clock.nanosec = divmod(self.clock_ns, NS)
        self.clock_pub.publish(clock)

    def play(self, frames: list[tuple[int, str, bytes]], offset_ns: int, encoding: str | None = None) -> None:
        """Publish frames at their recorded rate (slower when the node takes longer: each message waits
        for the node's acknowledgement of the one before), stamps (and /clock) shifted by offset_ns."""
        start_wall, start_t = time.monotonic(), frames[0][0]
        for t, topic, raw in frames:
            while time.monotonic() - start_wall < (t - start_t) / NS:
                rclpy.spin_once(self, timeout_sec=0.002)
            self.set_clock(t + offset_ns)
            message = deserialize_message(raw, Image)
            stamp = message.header.stamp.sec * NS + message.header.stamp.nanosec + offset_ns
            message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, NS)
            if encoding is not None and topic == COLOUR:
                message.encoding = encoding
            self.sent[stamp] += 1
            self.pub[topic].publish(message)
            self.wait_for_ack(stamp)

    def call(self, client, request, timeout: float = 10.0):
        if not client.wait_for_service(timeout_sec=timeout):
            raise RuntimeError(f"service {client.srv_name} not available")
        future = client.call_async(request)
        end = time.monotonic() + timeout
        while not future.done() and time.monotonic() < end:
            self.spin_for(0.01)
        return future.result()


def disabled_then_bag(driver: Driver, frames: list, result: dict) -> None:
    """Phases 1 and 2: frames while disabled, the enable service, the whole bag."""
    phase = result["phases"]
    driver.play([f for f in frames if f[0] < frames[0][0] + NS], driver.clock_ns + NS - frames[0][0])
    driver.spin_for(0.6)
    phase["disabled"] = len(driver.received)
    response = driver.call(driver.enable, SetBool.Request(data=True))
    phase["enable_response"] = [response.success, response.message]
    offset = driver.clock_ns + NS - frames[0][0]
    result["bag_offset_ns"] = offset
    first = len(driver.received)
    driver.play(frames, offset)
    phase["bag"] = [first, len(driver.received)]
    result["last_frame_ns"] = frames[-1][0] + offset


def stall_and_bad_input(driver: Driver, frames: list, result: dict) -> None:
    """Phases 3 to 5: a stalled camera, a frame of a wrong encoding, a bad parameter."""
    phase = result["phases"]
    start = len(driver.received)
    driver.spin_for(1.5)
    phase["stall"] = [start, len(driver.received)]
    good = [f for f in frames if f[0] < frames[0][0] + NS // 2]
    start = len(driver.received)
    driver.play(good, driver.clock_ns + NS - frames[0][0])
    driver.spin_for(0.1)
    before_bad = len(driver.received)
    driver.play(good[:2], driver.clock_ns + NS // 10 - good[0][0], encoding="yuv422")
    driver.spin_for(0.1)
    after_bad = len(driver.received)
    driver.play(good, driver.clock_ns + NS // 10 - good[0][0])
    driver.spin_for(0.3)
    phase["bad_encoding"] = [start, before_bad, after_bad, len(driver.received)]
    value = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=-1.0)
    answer = driver.call(
        driver.set_params,
        SetParameters.Request(parameters=[ParameterMsg(name="follower.navigator.v_max", value=value)]),
    )
    phase["bad_parameter"] = [answer.results[0].successful, answer.results[0].reason]
    driver.spin_for(0.3)


def disable(driver: Driver, frames: list, result: dict) -> None:
    """Phase 6: one stop, then silence while frames still come."""
    start = len(driver.received)
    response = driver.call(driver.enable, SetBool.Request(data=False))
    driver.spin_for(0.3)
    middle = len(driver.received)
    good = [f for f in frames if f[0] < frames[0][0] + NS // 2]
    driver.play(good, driver.clock_ns + NS // 10 - good[0][0])
    driver.spin_for(0.5)
    result["phases"]["disable"] = [start, middle, len(driver.received), response.message]


def live_client(params: Path):
    """A Foxglove client of the node's live view when PARAMS sets `live_port` (else None)."""
    port = yaml.safe_load(params.read_text())[NODE]["ros__parameters"].get("live_port", 0)
    if not port:
        return None
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout: benchmarks/
    from benchmarks.live_client import LiveClient

    client = LiveClient(port)
    if not client.connected.wait(10):
        raise RuntimeError(f"no live view on port {port}")
    return client


def live_record(client) -> dict:
    """What the client saw: topics and schemas advertised, seconds to each subscription, messages per topic."""
    received = client.stop()
    return {
        "channels": {c["topic"]: [c["encoding"], c["schemaName"]] for c in received.channels.values()},
        "subscribed_at": received.subscribed_at,
        "counts": dict(Counter(topic for topic, *_ in received.messages)),
    }


def stop(node: subprocess.Popen) -> tuple[int, str]:
    """Ctrl-C the node; its exit code and its log."""
    if node.poll() is None:
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=10)
        except subprocess.TimeoutExpired:
            node.kill()
    code = node.wait()
    return code, node.stdout.read() if node.stdout else ""


def with_node(params: Path, out: Path, driver: Driver, result: dict, phases, command: list[str] | None = None) -> None:
    """Start the node on `params` (or by `command`), wait for its services, run `phases(driver)`, then
    stop the node and write `result` with what `driver` received and the node's exit code and log to `out`."""
    segmin = Path(sys.executable).with_name("segmin")
    node = subprocess.Popen(
        command or [str(segmin), "ros2", "follow", "--params", str(params)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        if not driver.enable.wait_for_service(timeout_sec=60):
            raise RuntimeError("the node's ~/enable service never appeared")
        driver.spin_for(0.5)
        phases(driver)
        result["alive"] = node.poll() is None
    finally:
        result["received"] = driver.received
        driver.destroy_node()
        rclpy.try_shutdown()
        result["node_exit"], result["node_log"] = stop(node)
        out.write_text(json.dumps(result))


def main() -> int:
    bag, params, out = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])
    command = json.loads(Path(sys.argv[4]).read_text()) if len(sys.argv) > 4 else None
    frames, bag_commands = read_bag(bag)
    rclpy.init()
    result: dict = {"bag_commands": bag_commands, "phases": {}}
    result["colour_frames"] = sum(1 for _, topic, _ in frames if topic == COLOUR)

    def phases(driver: Driver) -> None:
        client = live_client(params)
        disabled_then_bag(driver, frames, result)
        if client is not None:
            result["live"] = live_record(client)
        if command is None:
            stall_and_bad_input(driver, frames, result)
            disable(driver, frames, result)

    with_node(params, out, Driver(), result, phases, command)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    sys.exit(main())
