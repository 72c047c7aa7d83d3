"""Sensor faults injected into a simulated run (the `faults:` section of the nav-eval config).

Each `SimFault` spoils the camera frames the robot receives for a window of the run's time:

- `depth_dropout`: depth NaN (what a 32FC1 driver sends without returns) on `share` of the pixels
  of `region` (all, left or right image half), drawn from the run's seed;
- `zero_depth`: depth 0 (a RealSense's "no reading") on `region`;
- `frozen_frame`: the last frame before the fault repeated (image, depth and mask), a stalled driver;
- `frozen_depth`: the last depth frame before the fault repeated while the image (and the mask)
  stay live, a depth driver stalled behind a live colour stream;
- `black_frame`: a black image (a covered lens); the oracle's mask is then empty too, as a
  segmenter's would be.

Faults are configured as `SimFault`s (nav_eval.sim.config); this module spoils the frames.

The runtime must stop on each (`runtime.sensor_faults`); `fault_metrics` measures how fast, how
far the robot drove blind and how soon it drove again (docs/reference/metrics.md).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from segmin.nav_eval.sim.config import SimFault
from segmin.nav_eval.sim.row_env import CameraFrame
from segmin.nav_eval.sim.track import Trajectory

MOVING_SPEED = 0.01  # m/s: below this the robot stands (blind distance ends there)


def faults_read_colour(faults: list[SimFault]) -> bool:
    """Whether the runtime must get the image to see a fault: one that spoils the image, and a
    frozen depth stream (the runtime judges the frames that carry an image)."""
    return any(f.kind in ("frozen_frame", "frozen_depth", "black_frame") for f in faults)


class FaultInjector:
    """Spoils the frames of one run as its faults say (a new one per run)."""

    def __init__(self, faults: list[SimFault], seed: int) -> None:
        self.faults = faults
        self._rng = np.random.default_rng(seed)
        self._last: CameraFrame | None = None  # the newest frame delivered (what a frozen driver repeats)

    def __call__(self, frame: CameraFrame, t: float) -> CameraFrame:
        """The frame at run time `t` as the robot receives it."""
        fault = next((f for f in self.faults if f.active(t)), None)
        if fault is not None and fault.kind == "frozen_frame":
            return self._last if self._last is not None else frame
        if fault is not None and fault.kind == "frozen_depth":
            self._last = frame if self._last is None else dataclasses.replace(frame, depth=self._last.depth)
            return self._last
        self._last = frame if fault is None else self._spoil(frame, fault)
        return self._last

    def _spoil(self, frame: CameraFrame, fault: SimFault) -> CameraFrame:
        if fault.kind == "black_frame":
            rgb = None if frame.rgb is None else np.zeros_like(frame.rgb)
            return dataclasses.replace(frame, rgb=rgb, mask=np.zeros_like(frame.mask))
        depth = np.array(frame.depth, dtype=np.float32, copy=True)
        width = depth.shape[1]
        columns = {"all": slice(None), "left": slice(0, width // 2), "right": slice(width // 2, None)}[fault.region]
        region = depth[:, columns]
        if fault.kind == "zero_depth":
            region[:] = 0.0
        else:
            region[self._rng.random(region.shape) < fault.share] = np.nan
        return dataclasses.replace(frame, depth=depth)


FAULT_METRIC_KEYS = ("fault_stop_s", "fault_blind_m", "fault_resume_s")


def fault_metrics(
    faults: list[SimFault], trajectory: Trajectory, driving: list[tuple[float, bool]]
) -> dict[str, float]:
    """The worst over a run's faults (NaN without faults, or when one fault never stopped the
    robot or was never recovered from; docs/reference/metrics.md):

    - `fault_stop_s`: from the fault's start to the first stop command (NaN: no stop while it lasted);
    - `fault_blind_m`: the path driven from the fault's start until the robot stands (speed under
      MOVING_SPEED after the stop), or until the fault ends when it did not stand before;
    - `fault_resume_s`: from the fault's end to the first command that drives (NaN: the run ended first).

    `driving` is (time, the command in force drives) at every runtime step of the run."""
    per_fault: dict[str, list[float]] = {key: [] for key in FAULT_METRIC_KEYS}
    if not faults or not driving:
        return dict.fromkeys(FAULT_METRIC_KEYS, math.nan)
    times = np.array([t for t, _ in driving])
    moving = np.array([d for _, d in driving])
    step = np.hypot(np.diff(trajectory.x), np.diff(trajectory.y))
    for fault in faults:
        if fault.start_s >= times[-1]:
            continue  # the run ended before this fault began: nothing to measure, nothing failed
        during = np.flatnonzero((times >= fault.start_s) & (times < fault.end_s) & ~moving)
        stop = float(times[during[0]]) if during.size else math.nan
        standing = (trajectory.t >= stop) & (trajectory.t <= fault.end_s) & (np.abs(trajectory.v) < MOVING_SPEED)
        still = np.flatnonzero(standing) if during.size else np.zeros(0, dtype=int)
        blind_end = float(trajectory.t[still[0]]) if still.size else fault.end_s
        ticks = (trajectory.t[1:] > fault.start_s) & (trajectory.t[1:] <= blind_end)
        after = np.flatnonzero((times >= fault.end_s) & moving)
        values = {
            "fault_stop_s": stop - fault.start_s,
            "fault_blind_m": float(step[ticks].sum()),
            "fault_resume_s": float(times[after[0]]) - fault.end_s if after.size else math.nan,
        }
        for key, value in values.items():
            per_fault[key].append(value)
    # A fault never stopped for (or never recovered from) is the worst: NaN wins over any number.
    # No fault reached (the run ended first): NaN as without faults.
    return {
        key: math.nan if not values or any(map(math.isnan, values)) else max(values)
        for key, values in per_fault.items()
    }
