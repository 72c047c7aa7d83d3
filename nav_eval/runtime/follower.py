"""`RowFollower`: the runtime a robot runs, and the one nav-eval and `segmin replay` measure.

The camera delivers timestamped frames (`rgb`, `depth`, `t` in seconds) at its own rate; the
follower owns every other rate, from the timestamps alone (no wall clock, so a recording, the
simulator and a robot behave the same):

- Segmentation runs at `segment_hz` on a timer anchored at the first frame: the deadline
  s_k = t_0 + k / segment_hz is served by the latest frame with t <= s_k. A frame therefore is
  segmented when the next frame shows that a deadline passed (or at once if a deadline falls on
  its own timestamp); this is the paper's "20 Hz on the latest frame" with the 30 Hz camera.
- Commands run at `command_hz` (a divisor of `segment_hz`: each command falls on a segmentation
  deadline): the navigator ORs the last `fuse_frames` masks and applies one EMA step per
  command. Between commands `step` returns the command in force.
- A mask that no command will fuse is not computed (with 20 / 5 Hz and 3 masks, 15 of the 20
  per second are): the commands are the same, the CPU is spared.
- A mask given as a future (a background segmenter's) is waited for only when a command needs
  it: the masks of deadlines between commands join the fusion window, in deadline order, at the
  next command. The commands are the same; the segmentation of those frames overlaps whatever
  the caller does until then (in nav-eval, rendering the next frames).

Timing faults, all decided from timestamps:

- frames out of time order (or a repeated / non-finite timestamp): ValueError naming the frame;
- stale masks: a mask whose frame is older than `max_mask_age_s` at a command is not fused; a
  command with no fresh mask is a stop (valid False, reason "stale_masks");
- frame timeout: `command_at(now)` returns a stop once no frame came for `frame_timeout_s`
  (the robot's control loop calls it at its own rate), and the first frame after such a gap
  restarts the follower (timer re-anchored, masks and EMA cleared) and is reported with
  `stopped="frame_timeout"`.

Sensor faults, decided per frame and per command (`sensor_faults`, limits in
`RuntimeConfig.checks`): depth without readings where the navigator reads it, a black, white or
frozen image, and frames stamped far from the follower's clock (`step(now=...)`) each stop the
robot with a named reason (`FollowerOutput.stopped`, `RowFollower.faults`) as long as they hold;
the masks keep being fused, so the first command after good frames return drives again (from
rest: a stop restarts the EMA).

The follower drives any `MaskNavigator` (nav_eval.runtime.protocols) and hands it what it
declares in `inputs`, no more: depth may be None for a navigator that does not need it (SegMin,
SegZeros: the mask alone is then used, every vegetation pixel counts as near), while SegMinD and
SegCorridor refuse a frame without it; the image and the IMU's attitude reach `command` only when
declared, and frames must match a declared camera. What it declares is checked when the frame
arrives, not frames later at the command. numpy only: no torch, pybullet or matplotlib (this
module is part of the bare robot install).
"""

from __future__ import annotations

import math
from concurrent.futures import Future
from dataclasses import dataclass, field

import numpy as np

from .control import Command, stop_command
from .navigator import to_metres, validated_attitude, validated_rgb
from .protocols import MaskNavigator, Segmenter
from .sensor_faults import SensorChecks, SensorFaults, check_depth_range

# Timestamps within this many seconds are the same instant (sim times are tick * dt in floats).
TIME_EPS = 1e-6


@dataclass(frozen=True)
class RuntimeConfig:
    """Rates and timing limits of the runtime (defaults: the paper's 20 Hz masks, 5 Hz commands),
    and the limits of its sensor checks (`checks`, a `SensorChecks`)."""

    segment_hz: int = 20
    command_hz: int = 5
    max_mask_age_s: float = 0.5  # a mask older than this at a command is not fused
    frame_timeout_s: float = 0.5  # no frame for longer than this -> stop
    checks: SensorChecks = field(default_factory=SensorChecks)

    def __post_init__(self) -> None:
        for name in ("segment_hz", "command_hz"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if self.segment_hz % self.command_hz:
            raise ValueError(
                f"segment_hz ({self.segment_hz}) must be a multiple of command_hz ({self.command_hz}): "
                "every command falls on a segmentation deadline"
            )
        for name in ("max_mask_age_s", "frame_timeout_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a finite number of seconds > 0, got {value!r}")
        if not isinstance(self.checks, SensorChecks):
            raise ValueError(f"checks must be a SensorChecks, got {self.checks!r}")


@dataclass(frozen=True)
class FollowerOutput:
    """What `RowFollower.step` returns for one frame."""

    t: float  # the frame's timestamp
    command: Command  # the command in force after this frame
    command_t: float | None  # when that command was computed (None before the first)
    fresh: bool  # a command was computed at this frame
    segmented: int  # masks computed at this frame
    fused: np.ndarray | None  # fused mask of a fresh command (None otherwise)
    depth: np.ndarray | None  # depth (metres) of a fresh command
    # "frame_timeout" / "stale_masks" when this frame stopped the robot; a sensor fault's reason
    # (sensor_faults.REASONS) on every frame while it holds
    stopped: str | None = None


@dataclass
class _Frame:
    t: float
    rgb: np.ndarray | None
    depth: np.ndarray | None
    mask: np.ndarray | Future[np.ndarray] | None = None  # None: segment rgb
    attitude: tuple[float, float] | None = None  # the IMU's (roll, pitch) at the frame


STOP = stop_command()


class RowFollower:
    """Segmenter + navigator under the runtime's timing (see the module docstring).

    `segmenter` may be None when every frame comes with its mask (the simulator, recorded masks).
    """

    def __init__(
        self, segmenter: Segmenter | None, navigator: MaskNavigator, config: RuntimeConfig | None = None
    ) -> None:
        self.segmenter = segmenter
        self.navigator = navigator
        self.config = config or RuntimeConfig()
        check_depth_range(navigator.config.depth_threshold, self.config.checks)
        self._ratio = self.config.segment_hz // self.config.command_hz
        self._sensors = SensorFaults(self.config.checks)
        self.reset()

    def reset(self) -> None:
        """Forget frames, masks and the EMA: the next frame starts the timers."""
        self.navigator.reset()
        self._sensors.reset()
        self._t0: float | None = None
        self._next_k = 0
        self._last: _Frame | None = None
        self._command = STOP
        self._command_t: float | None = None
        self._newest_depth: np.ndarray | None = None
        self._newest_depth_measured = False  # the newest depth is a frame's, not the stand-in for none
        self._newest_attitude: tuple[float, float] | None = None
        self._newest_rgb: np.ndarray | None = None
        self._waiting: list[tuple[_Frame, int]] = []  # (frame, deadline) whose mask future waits for a command

    # ---- the robot's calls ----------------------------------------------------------------------
    def step(
        self,
        rgb: np.ndarray | None,
        depth: np.ndarray | None,
        t: float,
        *,
        mask: np.ndarray | Future[np.ndarray] | None = None,
        attitude: object = None,
        now: float | None = None,
        driving: bool | None = None,
    ) -> FollowerOutput:
        """Take one camera frame at time `t` (seconds); return the command in force.

        `mask` replaces the segmenter for this frame when given (the simulator's exact mask, or a
        future from a background segmenter); `rgb` may then be None (SegCorridor's trunk test then
        trusts the mask alone, without its colour check). `attitude` is the IMU's
        (roll, pitch) in radians at the frame (REP 103), for navigators that level the depth
        points (SegCorridor); None: level ground assumed. `now` is the follower's clock when the
        frame arrives (the node's): a stamp further from it than `checks.max_clock_offset_s` stops
        the robot ("clock_offset"); None (the simulator, a replay): not checked. `driving` says
        whether the commands reach the wheels (the node: driving enabled); None: they do whenever
        one moves. A still image is judged frozen only while the robot drives, so a robot held
        still sees its still scene without a stop that would outlast it. Raises ValueError
        for a frame out of time order, with mismatched sizes, without what the navigator declares
        it needs, or with an invalid attitude.
        """
        t = _check_time(t, self._last.t if self._last is not None else None)
        inputs = self.navigator.inputs
        if depth is not None:
            depth = np.asarray(depth)
            if rgb is not None and np.shape(rgb)[:2] != depth.shape[:2]:
                raise ValueError(
                    f"frame at t={t:.6f} s: depth is {depth.shape[1]}x{depth.shape[0]}, "
                    f"rgb is {np.shape(rgb)[1]}x{np.shape(rgb)[0]}"
                )
            if inputs.camera is not None and depth.shape[:2] != inputs.camera.frame_shape:
                raise ValueError(
                    f"frame at t={t:.6f} s: depth is {depth.shape[1]}x{depth.shape[0]} but the navigator's "
                    f"camera is {inputs.camera.width}x{inputs.camera.height}"
                )
            if inputs.rgb:  # refused now, not frames later at its command
                try:
                    validated_rgb(rgb, depth.shape[:2])
                except ValueError as exc:
                    raise ValueError(f"frame at t={t:.6f} s: {exc}") from None
        elif inputs.depth:
            raise ValueError(
                f"{self.navigator.config.method} needs depth: give depth frames, or use segmin "
                f"(which then runs on the mask alone)"
            )
        frame = _Frame(t, rgb, depth, mask, validated_attitude(attitude))
        stopped = None
        if self._last is not None and t - self._last.t > self.config.frame_timeout_s + TIME_EPS:
            stopped = "frame_timeout"
            self.reset()
        if self._t0 is None:
            self._t0 = t
        command = self._command
        moving = command.valid and (command.v != 0.0 or command.omega != 0.0) and driving is not False
        self._sensors.on_frame(rgb, t, None if now is None else _seconds(now, "follower clock"), moving, depth)
        fault = self._sensors.reason
        if fault is not None and command.valid:  # at once, not at the next command
            self._command = self.navigator.stop()
        previous, self._last = self._last, frame
        return self._run_deadlines(frame, previous, stopped)

    def command_at(self, now: float) -> Command:
        """The command to send at time `now`: the one in force, or a stop once no frame came for
        `frame_timeout_s` (call it from the control loop, which runs even when the camera stalls).

        `now` must be a finite number of seconds (ValueError otherwise, as for a frame's
        timestamp): a NaN clock would never time out and keep the last command in force."""
        now = _seconds(now, "command time")
        if self._last is None or now - self._last.t > self.config.frame_timeout_s + TIME_EPS:
            return STOP
        return self._command

    @property
    def faults(self) -> dict[str, str]:
        """The sensor faults that hold now: reason (`sensor_faults.REASONS`) -> what was seen."""
        return dict(self._sensors.active)

    @property
    def sensor_fault(self) -> tuple[str, str] | None:
        """(reason, what was seen) of the fault a stop names now (the first in REASONS order), or None."""
        reason = self._sensors.reason
        return None if reason is None else (reason, self._sensors.active[reason])

    @property
    def last_frame_t(self) -> float | None:
        """Timestamp of the latest frame taken (None before the first or after a reset)."""
        return None if self._last is None else self._last.t

    def needs_frame(self, t: float, t_next: float) -> bool:
        """Whether a frame at `t`, followed by one at `t_next`, would be segmented for a command.

        The simulator asks before rendering, so it renders only the frames that matter.
        """
        if self._t0 is None or (self._last is not None and t - self._last.t > self.config.frame_timeout_s + TIME_EPS):
            return True  # the first frame (of a restart) always serves deadline 0
        hz = self.config.segment_hz
        k = max(self._next_k, math.ceil((t - self._t0) * hz - TIME_EPS * hz))
        while self._deadline(k) < t_next - TIME_EPS:
            if self._used(k):
                return True
            k += 1
        return False

    # ---- internals ---------------------------------------------------------------------------
    def _deadline(self, k: int) -> float:
        assert self._t0 is not None
        return self._t0 + k / self.config.segment_hz

    def _used(self, k: int) -> bool:
        """Deadline k's mask is fused by the next command (at deadline ceil(k / r) * r)."""
        command_k = -(-k // self._ratio) * self._ratio
        return command_k - k < self.navigator.config.fuse_frames

    def _run_deadlines(self, frame: _Frame, previous: _Frame | None, stopped: str | None) -> FollowerOutput:
        assert self._t0 is not None
        hz = self.config.segment_hz
        due = math.floor((frame.t - self._t0) * hz + TIME_EPS * hz)
        fresh, segmented = False, 0
        fused_out = depth_out = None
        for k in range(self._next_k, due + 1):
            deadline = self._deadline(k)
            source = frame if deadline >= frame.t - TIME_EPS else previous
            if source is not None and self._used(k):
                segmented += self._push(source, k)
            if k % self._ratio == 0:
                fresh = True
                fused_out, depth_out, why = self._emit(deadline)
                stopped = stopped or why
        self._next_k = max(self._next_k, due + 1)
        if stopped is None and not self._command.valid:
            stopped = self._sensors.reason  # a fault that holds: named on every frame until it clears
        return FollowerOutput(
            t=frame.t,
            command=self._command,
            command_t=self._command_t,
            fresh=fresh,
            segmented=segmented,
            fused=fused_out,
            depth=depth_out,
            stopped=stopped,
        )

    def _push(self, source: _Frame, k: int) -> int:
        """Push the mask of `source` for deadline k, or queue a mask future that no command needs
        yet (k is not a command deadline); returns 1 when it had to be computed."""
        if isinstance(source.mask, Future) and k % self._ratio != 0:
            queued = any(w is source for w, _ in self._waiting)  # a frame may serve two deadlines
            self._waiting.append((source, k))
            return 0 if queued else 1
        self._push_waiting()
        return self._push_now(source, k)

    def _push_waiting(self) -> None:
        """Push the queued mask futures, waiting for them, in their deadlines' order."""
        waiting, self._waiting = self._waiting, []
        for source, k in waiting:
            self._push_now(source, k)

    def _push_now(self, source: _Frame, k: int) -> int:
        """Push the mask of `source` for deadline k now; returns 1 when it had to be computed."""
        computed = 0
        if source.mask is None:
            if source.rgb is None:
                raise ValueError(
                    f"frame at t={source.t:.6f} s is needed for segmentation (deadline "
                    f"{self._deadline(k):.6f} s) but came without an image"
                )
            if self.segmenter is None:
                raise ValueError(
                    f"frame at t={source.t:.6f} s is needed for segmentation (deadline "
                    f"{self._deadline(k):.6f} s) but came without a mask, and this follower has no segmenter"
                )
            source.mask = self.segmenter.segment(source.rgb)
            computed = 1
        elif isinstance(source.mask, Future):  # a background segmenter's: wait for it now
            source.mask = source.mask.result()
            computed = 1
        mask = np.asarray(source.mask)
        if source.depth is None:
            depth_m = np.full(mask.shape, self.navigator.config.depth_threshold, dtype=np.float32)
        else:
            depth_m = to_metres(source.depth)
        self.navigator.push_mask(mask, source.t)
        self._newest_depth = depth_m
        self._newest_depth_measured = source.depth is not None
        self._newest_attitude = source.attitude
        self._newest_rgb = None if source.rgb is None else np.asarray(source.rgb)
        return computed

    def _emit(self, at: float) -> tuple[np.ndarray | None, np.ndarray | None, str | None]:
        """Compute the command at deadline time `at` (stale masks left out)."""
        self._push_waiting()
        fused = self.navigator.fused_mask(not_before=at - self.config.max_mask_age_s - TIME_EPS)
        self._command_t = at
        if fused is None or self._newest_depth is None:
            self._command = self.navigator.stop()
            return None, None, "stale_masks"
        self._sensors.on_command(fused, self._newest_depth if self._newest_depth_measured else None)
        fault = self._sensors.reason
        if fault is not None:
            self._command = self.navigator.stop()
            return fused, self._newest_depth, fault
        inputs = self.navigator.inputs
        self._command = self.navigator.command(
            fused,
            self._newest_depth,
            self._newest_attitude if inputs.attitude else None,
            self._newest_rgb if inputs.rgb else None,
        )
        return fused, self._newest_depth, None


def _seconds(t: object, what: str) -> float:
    """`t` as a finite float number of seconds, else ValueError naming `what`."""
    try:
        value = float(t)  # type: ignore[arg-type]  # anything float() takes; the rest is refused below
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number of seconds, got {t!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{what} must be finite, got {t!r}")
    return value


def _check_time(t: float, previous: float | None) -> float:
    """A finite timestamp strictly after the previous frame's, else ValueError naming both."""
    value = _seconds(t, "frame timestamp")
    if previous is not None and value <= previous:
        raise ValueError(
            f"frame at t={value:.6f} s is not after the previous frame (t={previous:.6f} s): "
            "frames must come in time order"
        )
    return value
