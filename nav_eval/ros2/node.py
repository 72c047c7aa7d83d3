"""The ROS 2 row-follower node: `FollowerCore` wired to rclpy. Started by `segmin ros2 follow`.

Subscribes (sensor-data QoS: best effort, keep last 1, so a late frame is replaced, never
queued behind) to the colour image and the aligned depth (`Image`, or `CompressedImage` on a
topic ending in /compressed or /compressedDepth, as image_transport names them). Publishes
`Twist` (or `TwistStamped`) on `cmd_vel`, optionally `~/overlay` (the mask and the chosen
column on the image), `/diagnostics` and `~/frame_acks` (the header of each image message once
handled: a player that waits for it feeds the node frame by frame, so the commands depend on the
images' stamps alone, not on when DDS delivered them) and, with `live_port`, the live view to
Foxglove (`nav_eval.live`: a WebSocket server, no ROS topic). The service `~/enable` (std_srvs/SetBool) and the
parameter `enabled` start and stop driving; both are off at start-up.

One single-threaded executor runs the callbacks: the images (segmentation runs there), the
diagnostics, the service and parameter changes, which wait at most one step. The watchdog (and,
with `publish_on_timer`, every command) runs on a thread of its own that sleeps to absolute
deadlines on the node's clock (`Clock.sleep_until`: the system clock, or /clock with
use_sim_time), not on an executor timer, so inference never delays it; with `publish_on_timer`
its ticks are phase-locked to the runtime's command deadlines (`phase.CommandPhase`). rclpy's
multi-threaded executor was measured slower here: on 2 cores its Python dispatch delayed image
callbacks by 5-30 ms and dropped a third of the frames. A parameter set while running is checked as at start-up
(`params.node_params`): a bad value is refused with its reason, logged, and the robot stopped;
a good one is applied at the next frame (the runtime restarts: masks and EMA cleared). Topics
and outputs, and the method (it chooses the navigator's parameters), are read-only after start-up.

rclpy and the message packages are those of the environment: a robot's sourced ROS 2, or the
community wheels (`.ci/ros_env.sh`). Nothing here is imported by the rest of segmin.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Twist, TwistStamped
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.time import Time
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, Imu
from std_msgs.msg import Header
from std_srvs.srv import SetBool

from segmin.nav_eval.replay.video import overlay
from segmin.nav_eval.ros2.core import FollowerCore, Outgoing
from segmin.nav_eval.ros2.params import STARTUP_ONLY, NodeParams, as_values, describe, node_params
from segmin.nav_eval.ros2.timing import CommandTiming
from segmin.nav_eval.runtime.follower import FollowerOutput

# The command thread wakes at its deadline but must then take the GIL, which an executor thread in
# pure Python (message conversion, callbacks) keeps for up to the switch interval, 5 ms by default.
# On the project's loaded 2-core machine a thread sleeping to 5 Hz deadlines beside a GIL-bound
# thread woke p99 80-92 ms late with 5 ms, 35-47 ms with 0.5 ms (18-27 ms with no GIL contention).
SWITCH_INTERVAL_S = 0.0005
WARM_UP_RUNS = 3
SENSOR_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)


def load_segmenter(params: NodeParams) -> Any:
    """The segmenter of `params` (ValueError naming the parameter when it cannot be loaded): the
    runtime's `load_segmenter`, so a shipped name runs its INT8 LiteRT file where LiteRT is
    installed, as everywhere else.

    onnxruntime's threads busy-wait only with `inference_spin`: on 2 idle cores spinning gives the
    lowest latency, but on a busy computer it takes the cores the camera driver and DDS need.
    Warmed up here: the first runs allocate and are several times slower."""
    from segmin.nav_eval.runtime.segmenter import load_segmenter as load

    if not params.node.model:
        raise ValueError("parameter model: not set (give a shipped model name or an exported .onnx / .tflite file)")
    try:
        segmenter = load(params.node.model, threads=params.node.threads, spin=params.node.inference_spin)
    except (OSError, ValueError) as exc:
        raise ValueError(f"parameter model: {exc}") from None
    blank = np.zeros((*segmenter.input_size, 3), dtype=np.uint8)
    for _ in range(WARM_UP_RUNS):
        segmenter.segment(blank)
    return segmenter


def _image_type(topic: str) -> type:
    return CompressedImage if topic.rstrip("/").endswith(("/compressed", "/compressedDepth")) else Image


def live_view(port: int) -> Any:
    """The live view on `port` (parameter live_port), None when 0: streams what the node computes."""
    if not port:
        return None
    from segmin.nav_eval.live.publisher import LiveView
    from segmin.nav_eval.live.server import LIVE_TYPES, LiveServer

    return LiveView(LiveServer(LIVE_TYPES, port))


class RowFollowerNode(Node):
    """See the module docstring."""

    def __init__(self, name: str, params: NodeParams, segmenter: Any, use_sim_time: bool = False) -> None:
        super().__init__(name, parameter_overrides=[Parameter("use_sim_time", value=use_sim_time)])
        self.params = params
        self.segmenter = segmenter
        self._values = as_values(params)  # as declared; a change is checked with the others
        for key, value in self._values.items():
            self.declare_parameter(
                key, value, ParameterDescriptor(description=describe(key), read_only=key in STARTUP_ONLY)
            )
        settings = params.node
        self.core = FollowerCore(params, segmenter, self._publish, self.get_logger().warning)
        self._pending: tuple[NodeParams, Any] | None = None
        self._pending_lock = threading.Lock()
        self.create_subscription(_image_type(settings.colour_topic), settings.colour_topic, self._on_colour, SENSOR_QOS)
        if settings.depth_topic:
            self.create_subscription(
                _image_type(settings.depth_topic), settings.depth_topic, self._on_depth, SENSOR_QOS
            )
        self._subscribe_corridor_inputs(settings)
        self._cmd = self.create_publisher(TwistStamped if settings.twist_stamped else Twist, settings.cmd_vel_topic, 10)
        self._overlay = self.create_publisher(Image, "~/overlay", 1) if settings.publish_overlay else None
        self._diagnostics = (
            self.create_publisher(DiagnosticArray, "/diagnostics", 10) if settings.publish_diagnostics else None
        )
        # Reliable with a queue: a player waiting for each acknowledgement must not miss one.
        self._acks = self.create_publisher(Header, "~/frame_acks", 100) if settings.publish_frame_acks else None
        self._live = live_view(settings.live_port)
        self.timing = CommandTiming()
        self._stopping = threading.Event()
        self._command_thread = threading.Thread(target=self._command_loop, name="commands", daemon=True)
        self._command_thread.start()
        if self._diagnostics is not None:
            self.create_timer(1.0, self._diagnose)
        self.create_service(SetBool, "~/enable", self._on_enable)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._frames_at_diagnosis = 0
        self.get_logger().info(
            f"{params.navigator.method} on {settings.colour_topic}"
            + (f" + {settings.depth_topic}" if settings.depth_topic else " (no depth)")
            + f" -> {settings.cmd_vel_topic}; driving {'enabled' if settings.enabled else 'disabled (call ~/enable)'}"
        )
        # Which file a shipped name runs depends on what is installed (its INT8 LiteRT file with
        # segmin[litert], else its ONNX file): the log says which.
        self.get_logger().info(f"segmenter: {segmenter!r}, {settings.threads} threads")

    def _subscribe_corridor_inputs(self, settings: Any) -> None:
        """SegCorridor's CameraInfo and Imu, subscribed at start-up when it is the method (an IMU at
        200 Hz would cost the other methods CPU for nothing)."""
        if self.params.navigator.method != "segcorridor":
            return
        intrinsics_given = self.params.follower.camera.intrinsics_given
        if settings.camera_info_topic and not intrinsics_given:
            self.create_subscription(
                CameraInfo,
                settings.camera_info_topic,
                lambda m: self.core.on_camera_info(m, self._seconds()),
                SENSOR_QOS,
            )
        if settings.imu_topic:
            self.create_subscription(
                Imu,
                settings.imu_topic,
                lambda m: self.core.on_imu(m, self._seconds()),
                SENSOR_QOS,
            )
        source = "the parameters" if intrinsics_given else f"CameraInfo on {settings.camera_info_topic}"
        imu = f"roll and pitch from {settings.imu_topic}" if settings.imu_topic else "no IMU: level ground"
        self.get_logger().info(f"segcorridor: camera intrinsics from {source}; {imu}")

    def _seconds(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    # ---- images --------------------------------------------------------------------------------
    def _on_colour(self, message: Any, info: Any) -> None:
        stamp = message.header.stamp
        self.timing.image_received(stamp.sec * 10**9 + stamp.nanosec, int(info["received_timestamp"]))
        self._apply_pending()
        output = self.core.on_colour(message, self._seconds())
        self._overlay_out(output, message)
        self._live_out(output)
        self._acknowledge(message)

    def _on_depth(self, message: Any) -> None:
        self._apply_pending()
        output = self.core.on_depth(message, self._seconds())
        self._overlay_out(output, None)
        self._live_out(output)
        self._acknowledge(message)

    def _acknowledge(self, message: Any) -> None:
        """After the command from `message` (if any) went out: a player waiting for this sends the next."""
        if self._acks is not None:
            self._acks.publish(message.header)

    def _overlay_out(self, output: FollowerOutput | None, message: Any) -> None:
        if self._overlay is None or output is None or not output.fresh or self.core.last_rgb is None:
            return
        image = overlay(self.core.last_rgb, output.fused, output.command.target_column)
        out = Image()
        if message is not None:
            out.header = message.header
        out.height, out.width = image.shape[:2]
        out.encoding, out.step = "rgb8", 3 * image.shape[1]
        out.data = np.ascontiguousarray(image).tobytes()
        self._overlay.publish(out)

    def _live_out(self, output: FollowerOutput | None) -> None:
        """The runtime's step to the live view (`live_port`), drawn on the frame it stepped."""
        if self._live is not None and output is not None and self.core.follower is not None:
            self._live.step(output.t, self.core.last_rgb, output, self.core.follower.navigator)

    # ---- commands ------------------------------------------------------------------------------
    def _publish(self, outgoing: Outgoing) -> None:
        twist = Twist()
        twist.linear.x, twist.angular.z = float(outgoing.command.v), float(outgoing.command.omega)
        if not self.params.node.twist_stamped:
            self._cmd.publish(twist)
            self._timed(outgoing)
            return
        stamped = TwistStamped()
        stamped.header.frame_id = self.params.node.base_frame
        stamped.header.stamp = outgoing.stamp if outgoing.stamp is not None else self.get_clock().now().to_msg()
        stamped.twist = twist
        self._cmd.publish(stamped)
        self._timed(outgoing)

    def _timed(self, outgoing: Outgoing) -> None:
        stamp = outgoing.stamp
        self.timing.published(
            None if stamp is None else stamp.sec * 10**9 + stamp.nanosec,
            time.time_ns(),
            time.monotonic(),
            outgoing.paced,
        )

    def _command_loop(self) -> None:
        """The watchdog's thread: `core.tick` at command_hz on absolute deadlines of the node's clock
        (with `publish_on_timer`, phase-locked to the runtime's command deadlines).

        A deadline missed (a loaded machine) is skipped, not caught up in a burst; a clock that
        jumps (a new /clock source) restarts the schedule."""
        self._raise_priority()
        clock = self.get_clock()
        deadline = clock.now()
        while not self._stopping.is_set():
            period = Duration(nanoseconds=10**9 // self.core.params.runtime.command_hz)
            deadline = self._next_tick(deadline, period)
            if not clock.sleep_until(deadline, context=self.context):
                if not self.context.ok():
                    return
                deadline = clock.now()  # ROS time switched on or off: restart the schedule
                continue
            if self._stopping.is_set():
                return
            self._watchdog()
            now = clock.now()
            if now - deadline > period:
                deadline = now

    def _raise_priority(self) -> None:
        """SCHED_FIFO for this thread at `command_priority` (0: leave it). On 2 busy cores a normal
        thread woke up to 50 ms late; at SCHED_FIFO within 6 ms. Refused (no rtprio limit, no
        CAP_SYS_NICE): one log line, and the thread runs at normal priority."""
        priority = self.params.node.command_priority
        if not priority:
            return
        try:
            os.sched_setscheduler(threading.get_native_id(), os.SCHED_FIFO, os.sched_param(priority))
        except OSError as exc:
            self.get_logger().warning(
                f"parameter command_priority: SCHED_FIFO {priority} refused ({exc.strerror}): the command thread runs "
                "at normal priority (raise the rtprio limit, e.g. in /etc/security/limits.conf, or grant CAP_SYS_NICE)"
            )
            return
        self.get_logger().info(f"command thread: SCHED_FIFO priority {priority}")

    def _next_tick(self, previous: Time, period: Duration) -> Time:
        if not self.core.params.node.publish_on_timer:
            return previous + period
        seconds = self.core.schedule_tick(previous.nanoseconds * 1e-9)
        return Time(nanoseconds=round(seconds * 1e9), clock_type=previous.clock_type)

    def destroy_node(self) -> None:
        """Stop the command thread first (it wakes within one period), so it never publishes on a destroyed node."""
        self._stopping.set()
        self._command_thread.join(timeout=2.0)
        if self._live is not None:
            self._live.server.close()
        super().destroy_node()

    def _watchdog(self) -> None:
        now = self._seconds()
        self.core.tick(now, now)

    def _on_enable(self, request: Any, response: Any) -> Any:
        response.message = self.core.set_enabled(bool(request.data))
        response.success = True
        self.get_logger().info(response.message)
        return response

    # ---- parameters ----------------------------------------------------------------------------
    def _on_set_parameters(self, changes: list[Parameter]) -> SetParametersResult:
        values = {**self._values, **{p.name: p.value for p in changes if p.name != "use_sim_time"}}
        try:
            params = node_params(values)
            segmenter = self.segmenter
            loaded = (self.params.node.model, self.params.node.threads, self.params.node.inference_spin)
            if (params.node.model, params.node.threads, params.node.inference_spin) != loaded:
                segmenter = load_segmenter(params)
        except ValueError as exc:
            self.get_logger().error(f"refused, robot stopped: {exc}")
            self.core.hold(str(exc), self._seconds())
            return SetParametersResult(successful=False, reason=str(exc))
        only_enabled = {k: v for k, v in values.items() if k != "enabled"} == {
            k: v for k, v in self._values.items() if k != "enabled"
        }
        if only_enabled:  # at once, from here
            self.get_logger().info(self.core.set_enabled(params.node.enabled))
        else:
            with self._pending_lock:
                self._pending = (params, segmenter)
        self.params, self._values = params, values
        return SetParametersResult(successful=True)

    def _apply_pending(self) -> None:
        """A parameter change takes effect here, on the image side, between two frames."""
        with self._pending_lock:
            pending, self._pending = self._pending, None
        if pending is not None:
            params, self.segmenter = pending
            self.core.reconfigure(params, self.segmenter)
            self.get_logger().info("parameters applied: the runtime restarts")

    # ---- diagnostics ---------------------------------------------------------------------------
    def _diagnose(self) -> None:
        now = self._seconds()
        values = self.core.status(now) | self.timing.summary(self.core.params.runtime.command_hz)
        frames = self.core.frames
        values["frame rate Hz"] = f"{frames - self._frames_at_diagnosis:.0f}"
        self._frames_at_diagnosis = frames
        why = self.core.stop_reason(now)
        status = DiagnosticStatus(
            level=DiagnosticStatus.OK
            if why is None
            else (DiagnosticStatus.ERROR if self.core.fault or self.core.sensor_fault else DiagnosticStatus.WARN),
            name=f"{self.get_name()}: row following",
            message="driving" if why is None else f"stopped: {why}",
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        assert self._diagnostics is not None
        self._diagnostics.publish(array)


def run(name: str, values: dict[str, Any], base: Path | None, ros_args: list[str]) -> int:
    """Start the node; a bad parameter or model refuses before rclpy starts (ValueError, one line)."""
    use_sim_time = bool(values.pop("use_sim_time", False))
    params = node_params(values, base)
    if params.node.live_port:  # a taken port or a missing [live] extra, before the model and rclpy start
        from segmin.nav_eval.live.server import check_port

        check_port(params.node.live_port, "parameter live_port")
    segmenter = load_segmenter(params)
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    rclpy.init(args=["segmin", "--ros-args", *ros_args] if ros_args else None)
    node = RowFollowerNode(name, params, segmenter, use_sim_time)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
