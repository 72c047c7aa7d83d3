"""Feeds the row-follower node bags with sensor faults; run by test_ros2_node.py in the ROS environment.

Usage (inside a network namespace holding only loopback, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST):

    ROSENV/bin/python tests/ros2_fault_driver.py SPEC.json PARAMS OUT.json

SPEC is a list of scenarios: {"bag", "bad_from_ns", "good_from_ns", "clock_lead_ns"}, bag times
(ns) of the first bad frame and of the first good frame after the fault. With driving enabled,
each bag is played frame by frame at its recorded rate, as `ros2_driver.py` plays one (each image
waits for the node's acknowledgement of the one before; /clock follows the stamps), its stamps
shifted to start after the last scenario's. Frames of another clock: from `bad_from_ns` on, /clock
runs `clock_lead_ns` ahead of the stamps, and the good frames after the fault are stamped on the
clock again (a jump forward, as a restarted camera driver's would be).

Scenarios start LOG_EVERY_S (the node's throttle of one line per reason) apart on the node's
clock, so each onset of a fault may log its line. Everything the driver receives (commands,
/diagnostics, the node's /rosout) is recorded with the bag time of the newest frame published
then, which is how the test measures stop and resume times in bag time.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Log
from rclpy.serialization import deserialize_message
from ros2_driver import NODE, NS, Driver, read_bag, with_node
from sensor_msgs.msg import Image
from std_srvs.srv import SetBool

SCENARIO_GAP_NS = 6 * NS  # more than the node's LOG_EVERY_S between two onsets of the same reason


class FaultDriver(Driver):
    def __init__(self) -> None:
        super().__init__()
        self.at: tuple[int, int] = (-1, 0)  # (scenario, bag time ns of the newest frame published)
        self.published: list[tuple[int, int, float]] = []  # (scenario, bag ns, wall) of each frame's first message
        self.commands: list[tuple[int, int, float, float, float]] = []  # (scenario, bag ns, wall, v, omega)
        self.diagnostics: list[tuple[int, int, str, dict[str, str]]] = []
        self.log: list[tuple[int, int, str]] = []
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self.create_subscription(Log, "/rosout", self._on_log, 100)

    def _on_cmd(self, message) -> None:
        super()._on_cmd(message)
        self.commands.append((*self.at, time.monotonic(), message.twist.linear.x, message.twist.angular.z))

    def _on_diagnostics(self, array: DiagnosticArray) -> None:
        for status in array.status:
            values = {kv.key: kv.value for kv in status.values}
            self.diagnostics.append((*self.at, status.message, values))

    def _on_log(self, entry: Log) -> None:
        if entry.name == NODE:
            self.log.append((*self.at, entry.msg))

    def play_scenario(self, index: int, frames: list, bad_from: int, good_from: int, lead: int) -> None:
        """Play `frames` at their recorded rate; /clock `lead` ns ahead of the stamps in [bad_from, good_from)."""
        offset = self.clock_ns + SCENARIO_GAP_NS - frames[0][0]
        start_wall, start_t = time.monotonic(), frames[0][0]
        for t, topic, raw in frames:
            while time.monotonic() - start_wall < (t - start_t) / NS:
                rclpy.spin_once(self, timeout_sec=0.002)
            shift = offset + (lead if t >= good_from else 0)
            self.set_clock(t + shift + (lead if bad_from <= t < good_from else 0))
            message = deserialize_message(raw, Image)
            stamp = message.header.stamp.sec * NS + message.header.stamp.nanosec + shift
            message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, NS)
            if self.at != (index, t):
                self.at = (index, t)
                self.published.append((index, t, time.monotonic()))
            self.sent[stamp] += 1
            self.pub[topic].publish(message)
            self.wait_for_ack(stamp)
        self.spin_for(0.3)


def main() -> int:
    spec, params, out = json.loads(Path(sys.argv[1]).read_text()), Path(sys.argv[2]), Path(sys.argv[3])
    rclpy.init()
    driver = FaultDriver()
    result: dict = {key: getattr(driver, key) for key in ("published", "commands", "diagnostics", "log")}

    def phases(driver: FaultDriver) -> None:
        response = driver.call(driver.enable, SetBool.Request(data=True))
        result["enable_response"] = [response.success, response.message]
        for index, scenario in enumerate(spec):
            frames, _ = read_bag(Path(scenario["bag"]))
            driver.play_scenario(
                index, frames, scenario["bad_from_ns"], scenario["good_from_ns"], scenario["clock_lead_ns"]
            )

    with_node(params, out, driver, result, phases)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    sys.exit(main())
