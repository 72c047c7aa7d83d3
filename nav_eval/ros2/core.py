"""The row-follower node without ROS: image messages in, commands out, every fault a stop.

`FollowerCore` owns the `RowFollower` (nothing of the runtime is re-implemented) and decides
what the node publishes; `node.py` only wires it to rclpy. Kept free of ROS so that its rules
are tested in the normal suite and the bench can drive it.

- Colour and depth messages are decoded (`replay.ros_images`) and paired by header stamp within
  `slop_s` (`replay.stamp_pairing`); a pair is one `RowFollower.step` at the colour stamp.
- With `publish_on_timer` false, a fresh command is published at once (the latency from image
  to `cmd_vel` is the step's own, the period jitters with it); the `tick(now)` watchdog, called
  at `command_hz`, publishes `command_at(now)` whenever no command went out for 1.5 periods: the
  command in force while frames come late, a stop once none came for `frame_timeout_s`. With
  `publish_on_timer` (the default), `tick`
  publishes every period (a regular period), and the node puts its ticks just after the
  runtime's command deadlines (`phase.CommandPhase`, fed here with when each command was ready),
  so a command waits only a small margin; one whose tick is further than `HOLD_SHARE` of a period
  away (a slow step missed it, or the lock is not there yet) goes out at once, without pacing the
  timer.
- Sensor faults (depth without readings, a black, white or frozen image, stamps far from the
  node's clock: `runtime.sensor_faults`) are the runtime's: it stops the robot with the fault's
  reason, and drives again when good frames return. The core passes the node's clock with each
  frame, logs one line per change of fault (at most one per reason every LOG_EVERY_S) and names
  the fault, with what was seen, in the diagnostics.
- Any bad frame (an encoding the decoder refuses, mismatched sizes, a stamp out of order) is a
  log line naming the topic (at most one per kind of problem every LOG_EVERY_S), the frame is dropped,
  and while enabled a stop goes out at once and the watchdog keeps the robot stopped until the
  runtime gives a fresh command. The node stays up. Frames without a partner (a depth frame
  with no colour frame within `slop_s`) are logged and counted but stop nothing by themselves:
  a robot that gets no pairs any more is stopped by the frame timeout.
- SegCorridor (`method: segcorridor`) needs the camera: from the parameters, or from the first
  `CameraInfo` on `camera_info_topic` (frames before it are refused, naming that topic; one whose
  size differs from the images' stops the robot, naming it too). Its `Imu` on `imu_topic` gives
  roll and pitch (`sensors.attitude_from_imu`); a frame with no IMU message within
  `imu_max_age_s` of it is stepped on level ground, with a log line (a stale IMU must not stop a
  robot that can still see its rows).
- `enabled` (off at start-up): while off the runtime still runs (diagnostics, overlay) but no
  command is published; switching off publishes one stop.

Thread safety: the image callbacks run one at a time (one callback group); the watchdog and the
enable service run in another group, so inference never delays them. They share a few
attributes under `_lock`, which is never held during inference.
"""

from __future__ import annotations

import re
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from segmin.nav_eval.replay.ros_images import (
    ImageMessageError,
    camera_from_info,
    decode_colour,
    decode_depth,
    stamp_seconds,
)
from segmin.nav_eval.replay.stamp_pairing import StampOrderError, StampPairer
from segmin.nav_eval.ros2.params import NodeParams
from segmin.nav_eval.ros2.phase import CommandPhase
from segmin.nav_eval.ros2.sensors import attitude_from_imu
from segmin.nav_eval.runtime.camera import CameraGeometry
from segmin.nav_eval.runtime.corridor import CorridorConfig
from segmin.nav_eval.runtime.follower import STOP, FollowerOutput, RowFollower
from segmin.nav_eval.runtime.follower_config import make_navigator
from segmin.nav_eval.runtime.navigator import Command

WATCHDOG_PERIODS = 1.5  # the watchdog speaks after this many command periods of silence
NUMBERS = re.compile(r"\d+(?:\.\d+)?")  # left out of a warning's kind (stamps, sizes, counts)
HOLD_SHARE = 0.5  # with publish_on_timer, a fresh command waits for its tick at most this share of a period
LOG_EVERY_S = 5.0  # each kind of bad frame or fault is logged at most this often (30 Hz of warnings helps no one)


@dataclass(frozen=True)
class Outgoing:
    """A command to publish, with the stamp it answers (the image's, or the clock's for a stop)."""

    command: Command
    stamp: Any  # a builtin_interfaces Time of the image that gave the command, or None: now
    reason: str | None = None  # why this is a stop
    paced: bool = False  # this publication sets the command rate (a fresh command at once, or a timer tick)


class FollowerCore:
    """See the module docstring. `publish(Outgoing)` and `log(str)` (a warning) are the node's."""

    def __init__(
        self,
        params: NodeParams,
        segmenter: Any,
        publish: Callable[[Outgoing], None],
        log: Callable[[str], None],
        timer: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.params = params
        self.publish = publish
        self.log = log
        self.segmenter = segmenter
        self._info_camera: CameraGeometry | None = None  # the latest CameraInfo's
        self._attitude: tuple[float, float, float] | None = None  # (stamp s, roll, pitch) of the latest Imu
        self.follower = self._new_follower()
        self.pairer = StampPairer(params.node.slop_s, max_pending=2)
        self._wall = timer  # times the steps (wall clock, also when the node runs on a bag's clock)
        self._lock = threading.Lock()
        self.enabled = params.node.enabled
        self.fault: str | None = None  # why the robot is held stopped (bad input), until a fresh command
        self._last_sent: float | None = None  # node clock of the last publication
        self.next_tick: float | None = None  # node clock of the command thread's next tick (publish_on_timer)
        self.phase = CommandPhase(1.0 / params.runtime.command_hz)
        self._stamp: Any = None  # stamp of the image that gave the command in force
        self._logged: dict[str, float] = {}  # kind of warning -> node clock of its last line
        self._sensor_reason: str | None = None  # the runtime's sensor fault at the last frame
        self.frames = 0
        self.rejected = 0
        self._unpaired = 0
        self.step_s: deque[float] = deque(maxlen=100)
        self.last_output: FollowerOutput | None = None
        self.last_rgb: np.ndarray | None = None

    def _new_follower(self) -> RowFollower | None:
        """The runtime of the parameters; None while SegCorridor waits for its camera's CameraInfo."""
        needs_camera = isinstance(self.params.navigator, CorridorConfig)
        camera = self.params.camera or self._info_camera
        if needs_camera and camera is None:
            return None
        return RowFollower(self.segmenter, make_navigator(self.params.follower, camera), self.params.runtime)

    # ---- SegCorridor's camera and IMU ----------------------------------------------------------
    def on_camera_info(self, message: Any, now: float) -> None:
        """A CameraInfo: SegCorridor's intrinsics (a new runtime when they change)."""
        node = self.params.node
        try:
            camera = camera_from_info(message, node.camera_info_topic, self.params.follower.camera)
        except ValueError as exc:
            self._reject(str(exc), now)
            return
        if camera != self._info_camera:
            self._info_camera = camera
            if isinstance(self.params.navigator, CorridorConfig) and self.params.camera is None:
                self.follower = self._new_follower()
                self.log(
                    f"{node.camera_info_topic}: camera {camera.width}x{camera.height}, fx {camera.fx:.1f}: runtime (re)started"
                )

    def on_imu(self, message: Any, now: float) -> None:
        """An Imu: the roll and pitch of the next frames (a bad one is logged and ignored)."""
        try:
            roll, pitch = attitude_from_imu(message, self.params.node.imu_topic)
        except ValueError as exc:
            self._warn(str(exc), now, "IMU ignored, level ground assumed")
            return
        self._attitude = (stamp_seconds(message), roll, pitch)

    def _frame_attitude(self, t: float, now: float) -> tuple[float, float] | None:
        """The IMU's (roll, pitch) for a frame at `t`, or None (level ground) when it is stale or absent."""
        topic = self.params.node.imu_topic
        if not topic:
            return None
        if self._attitude is None or abs(t - self._attitude[0]) > self.params.node.imu_max_age_s:
            age = (
                "no message yet"
                if self._attitude is None
                else f"newest {abs(t - self._attitude[0]):.3f} s from the frame"
            )
            self._warn(
                f"{topic}: stale ({age}; imu_max_age_s={self.params.node.imu_max_age_s})",
                now,
                "IMU ignored, level ground assumed",
            )
            return None
        return self._attitude[1:]

    def _camera_mismatch(self, shape: tuple[int, ...]) -> str | None:
        """Why SegCorridor cannot take a frame of `shape` (no camera yet, or another size), or None."""
        if not isinstance(self.params.navigator, CorridorConfig):
            return None
        node = self.params.node
        source = "follower.camera.width/height" if self.params.camera is not None else node.camera_info_topic
        camera = self.params.camera or self._info_camera
        if camera is None:
            return f"{source}: no CameraInfo yet (SegCorridor needs the intrinsics)"
        if tuple(shape[:2]) != camera.frame_shape:
            return (
                f"{source}: the camera is {camera.width}x{camera.height} but {node.colour_topic} images are "
                f"{shape[1]}x{shape[0]}"
            )
        return None

    # ---- the image callbacks -------------------------------------------------------------------
    def on_colour(self, message: Any, now: float) -> FollowerOutput | None:
        """A colour message; returns the runtime's output when it stepped."""
        topic = self.params.node.colour_topic
        try:
            t = stamp_seconds(message)
            rgb = decode_colour(message, topic)
            if not self.params.node.depth_topic:
                return self._step(rgb, None, t, message.header.stamp, now)
            pairs = self.pairer.add_colour(t, (rgb, message.header.stamp))
        except (ImageMessageError, StampOrderError) as exc:
            self._reject(f"{topic}: {exc}" if isinstance(exc, StampOrderError) else str(exc), now)
            return None
        return self._run_pairs(pairs, now)

    def on_depth(self, message: Any, now: float) -> FollowerOutput | None:
        """A depth message; returns the runtime's output when it completed a pair that stepped."""
        topic = self.params.node.depth_topic
        try:
            pairs = self.pairer.add_depth(stamp_seconds(message), decode_depth(message, topic)[0])
        except (ImageMessageError, StampOrderError) as exc:
            self._reject(f"{topic}: {exc}" if isinstance(exc, StampOrderError) else str(exc), now)
            return None
        return self._run_pairs(pairs, now)

    def _run_pairs(self, pairs: list, now: float) -> FollowerOutput | None:
        unpaired = self.pairer.dropped_colour + self.pairer.dropped_depth
        if unpaired > self._unpaired:  # logged, not a stop: the frame timeout stops a robot that gets no pairs
            self._unpaired = unpaired
            node = self.params.node
            self._warn(
                f"{node.colour_topic}+{node.depth_topic}: {unpaired} frame(s) so far had no partner within "
                f"slop_s={node.slop_s} s",
                now,
                "unpaired frames dropped",
            )
        output = None
        for colour, depth in pairs:
            rgb, stamp = colour.item
            output = self._step(rgb, depth.item, colour.t, stamp, now) or output
        return output

    def _step(
        self, rgb: np.ndarray, depth: np.ndarray | None, t: float, stamp: Any, now: float
    ) -> FollowerOutput | None:
        mismatch = self._camera_mismatch(rgb.shape)
        if mismatch is not None or self.follower is None:
            self._reject(mismatch or "no runtime", now)
            return None
        uses_attitude = self.follower.navigator.inputs.attitude
        attitude = self._frame_attitude(t, now) if uses_attitude else None
        start = self._wall()
        try:
            output = self.follower.step(rgb, depth, t, attitude=attitude, now=now, driving=self.enabled)
        except ValueError as exc:
            self._reject(f"{self.params.node.colour_topic}: {exc}", now)
            return None
        if self._note_sensor_fault(self.follower.sensor_fault, now) and not output.fresh:
            self._send_stop(output.stopped, now)  # found between commands (an image, the clock): at once
        took = self._wall() - start
        self.step_s.append(took)
        self.frames += 1
        self.last_output, self.last_rgb = output, rgb
        if output.fresh:
            on_timer = self.params.node.publish_on_timer
            with self._lock:  # the command thread reads the phase and the next tick
                if output.command_t is not None:
                    self.phase.observe(output.command_t, output.t, now + took)
                late = on_timer and self._misses_tick(now + took)
                self.fault = None
                self._stamp = stamp
                send = self.enabled and (late or not on_timer)
                if send:
                    self._last_sent = now
            if send:
                reason = None if output.command.valid else output.stopped
                self.publish(Outgoing(output.command, stamp, reason, paced=not on_timer))
        return output

    def schedule_tick(self, previous: float) -> float:
        """With publish_on_timer: the command thread's next tick after the one at `previous`
        (node clock, s), phase-locked to the runtime's command deadlines; remembered for the
        hold-or-send decision of fresh commands."""
        with self._lock:  # the image thread updates the phase
            self.next_tick = self.phase.next_tick(previous)
            return self.next_tick

    def _misses_tick(self, ready: float) -> bool:
        """Whether a command ready at `ready` (node clock) has no tick within HOLD_SHARE of a period
        ahead (a slow step missed its tick, or the timer is not locked yet): it then goes out at once.
        Called under `_lock`."""
        period = 1.0 / self.params.runtime.command_hz
        tick = self.next_tick
        return tick is None or not 0.0 <= tick - ready <= HOLD_SHARE * period

    def _reject(self, why: str, now: float) -> None:
        """Drop a frame: a log line (throttled per topic), the robot stopped until a fresh command."""
        self.rejected += 1
        self._warn(why, now, "frame dropped, robot stopped")
        self.hold(why, now)

    def hold(self, why: str, now: float) -> None:
        """Stop the robot now (when enabled) and keep it stopped until the runtime gives a fresh command."""
        with self._lock:
            self.fault = why
        self._send_stop(why, now)

    def _warn(self, why: str, now: float, what: str) -> None:
        """Log `what: why`, at most once per LOG_EVERY_S for each kind of problem: `why` with its
        numbers left out (a second kind on the same topic gets its own line; stamps and sizes that
        change from frame to frame do not make a new kind)."""
        self._log_throttled(NUMBERS.sub("#", why), f"{what}: {why}", now)

    def _log_throttled(self, kind: str, line: str, now: float) -> None:
        if now - self._logged.get(kind, -float("inf")) >= LOG_EVERY_S:
            self._logged[kind] = now
            self.log(line)

    def _note_sensor_fault(self, fault: tuple[str, str] | None, now: float) -> bool:
        """One log line when the runtime's sensor fault changes (at most one per reason every
        LOG_EVERY_S); True when a fault began with this frame."""
        reason = None if fault is None else fault[0]
        before, self._sensor_reason = self._sensor_reason, reason
        if reason == before:
            return False
        if fault is not None:
            self._log_throttled(f"sensor {reason}", f"robot stopped, sensor fault {reason}: {fault[1]}", now)
        else:
            self._log_throttled(
                f"sensor {before} cleared", f"sensor fault {before} cleared: the runtime drives again", now
            )
        return fault is not None

    def _send_stop(self, why: str | None, now: float) -> None:
        """Publish a stop now (when enabled), outside the command schedule."""
        with self._lock:
            send = self.enabled
            if send:
                self._last_sent = now
        if send:
            self.publish(Outgoing(STOP, None, why))

    # ---- the watchdog and the switch -----------------------------------------------------------
    def tick(self, now: float, stamp_now: float) -> None:
        """Watchdog at command_hz: `now` is the node clock, `stamp_now` the same instant in the
        images' time base (ROS time; sim time when the node runs on a bag's clock)."""
        period = 1.0 / self.params.runtime.command_hz
        on_timer = self.params.node.publish_on_timer
        with self._lock:
            quiet = self._last_sent is not None and now - self._last_sent < WATCHDOG_PERIODS * period
            if not self.enabled or (quiet and not on_timer):
                return
            self._last_sent = now
            fault, stamp = self.fault, self._stamp
        command = STOP if fault or self.follower is None else self.follower.command_at(stamp_now)
        reason = fault or (None if command.valid else self.stop_reason(stamp_now))
        self.publish(Outgoing(command, stamp if command.valid else None, reason, paced=on_timer))

    def reconfigure(self, params: NodeParams, segmenter: Any) -> None:
        """New parameters (checked by the node): a fresh runtime, masks and EMA cleared.

        Called from the image callbacks' group, between two frames."""
        self.params, self.segmenter = params, segmenter
        self.follower = self._new_follower()
        self.pairer = StampPairer(params.node.slop_s, max_pending=2)
        with self._lock:
            self.phase = CommandPhase(1.0 / params.runtime.command_hz)  # the runtime's grid starts again
        self._unpaired = 0
        if params.node.enabled != self.enabled:
            self.log(self.set_enabled(params.node.enabled))

    def set_enabled(self, enabled: bool) -> str:
        """Start or stop driving; returns what happened (the service's answer, the node's log line)."""
        with self._lock:
            before, self.enabled = self.enabled, bool(enabled)
            self._last_sent = None
        if before and not enabled:
            self.publish(Outgoing(STOP, None, "disabled"))
        return f"driving {'enabled' if enabled else 'disabled'}" + ("" if before != enabled else " (unchanged)")

    # ---- what the diagnostics say --------------------------------------------------------------
    def stop_reason(self, stamp_now: float) -> str | None:
        """Why the robot is stopped now, or None when it drives."""
        if not self.enabled:
            return "disabled"
        if self.fault:
            return self.fault
        if self.follower is None:
            return f"{self.params.node.camera_info_topic}: no CameraInfo yet"
        last = self.follower.last_frame_t
        if last is None:
            return "no frame yet"
        fault = self.follower.sensor_fault
        if fault is not None and fault[0] == "clock_offset":  # frames come, on another clock
            return f"{fault[0]}: {fault[1]}"
        if stamp_now - last > self.params.runtime.frame_timeout_s:
            return f"frame_timeout: no paired frame for {stamp_now - last:.2f} s"
        if fault is not None:
            return f"{fault[0]}: {fault[1]}"
        command = self.follower.command_at(stamp_now)
        if not command.valid:
            return (self.last_output.stopped if self.last_output else None) or "no target in the mask"
        return None

    def status(self, stamp_now: float) -> dict[str, str]:
        """Key -> value for the diagnostics."""
        steps = np.asarray(self.step_s, dtype=float)
        return {
            "frames stepped": str(self.frames),
            "frames rejected": str(self.rejected),
            "unpaired colour frames": str(self.pairer.dropped_colour),
            "unpaired depth frames": str(self.pairer.dropped_depth),
            "step time median ms": f"{1e3 * np.median(steps):.1f}" if steps.size else "-",
            "step time max ms": f"{1e3 * steps.max():.1f}" if steps.size else "-",
            "enabled": str(self.enabled),
            "sensor fault": self.sensor_fault or "-",
            "stopped because": self.stop_reason(stamp_now) or "-",
        }

    @property
    def sensor_fault(self) -> str | None:
        """The reason of the runtime's sensor fault now (`runtime.sensor_faults.REASONS`), or None."""
        fault = None if self.follower is None else self.follower.sensor_fault
        return None if fault is None else fault[0]
