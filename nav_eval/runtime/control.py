"""The control pieces every navigator shares: the command it returns, the limits it clips to and
the paper's EMA that smooths it.

They are written once so that the four methods cannot drift apart: SegCorridor's command is
smoothed by exactly the EMA of SegMin, SegMinD and SegZeros (Navone et al., section 2:
y_t = (1 - lambda) y_{t-1} + lambda u_t), and a stop is the same stop whoever issues it.
numpy only (part of the bare robot install).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Command:
    """One navigator output: smoothed velocities plus what they were computed from."""

    v: float
    omega: float
    target_column: float | None
    histogram: np.ndarray
    valid: bool


def stop_command(histogram: np.ndarray | None = None) -> Command:
    """An invalid (0, 0) command: the robot stands; `histogram` says what it saw, if anything."""
    return Command(
        v=0.0, omega=0.0, target_column=None, histogram=np.zeros(0) if histogram is None else histogram, valid=False
    )


def clip(value: float, low: float, high: float) -> float:
    """`value` limited to [low, high]."""
    return min(max(value, low), high)


class CommandSmoother:
    """The paper's EMA of (v, omega), one step per command; `rest()` restarts it from standstill.

    A navigator restarts it whenever it stops (no target, stale masks): the next command then
    ramps up from rest instead of from the velocity before the stop.
    """

    def __init__(self, ema_lambda: float) -> None:
        self.ema_lambda = ema_lambda
        self.v = 0.0
        self.omega = 0.0

    def rest(self) -> None:
        """Back to standstill: the next `update` starts from (0, 0)."""
        self.v = 0.0
        self.omega = 0.0

    def update(self, v: float, omega: float) -> tuple[float, float]:
        """One EMA step towards the unsmoothed (v, omega); returns the smoothed pair."""
        lam = self.ema_lambda
        self.v = (1.0 - lam) * self.v + lam * v
        self.omega = (1.0 - lam) * self.omega + lam * omega
        return self.v, self.omega


class DriftObserver:
    """Estimates a steady sideways drift d (m/s, > 0: towards the robot's left) from how the
    robot's offset to its path changes against what its heading explains: e' = v sin(psi) + d.

    A proportional-derivative law (pure pursuit is one) balances a steady drift only with a
    standing offset: a skid-steer robot creeping downhill across a slope holds the row off centre.
    Knowing d, the law can point the robot uphill by the drift angle instead. Unlike an integral of
    the offset it does not wind up on a start or a bend taken late: there the offset changes as the
    heading says, the innovation is zero and the estimate stays.

    Per update, with the offset e and heading psi relative to the path measured at stamp t (the
    time step is the stamps' difference, never an assumed rate) and v the commanded speed:
    d <- clip(d + min(1, dt / `time_constant`) (de/dt - v sin(psi) - d), -`limit`, +`limit`).
    Anti-windup: the clamp; a step whose offset changes faster than `max_lateral_speed` (a jump of
    the fit: a row lost through a gap, the other row found) or more than 1 s after the previous
    one is not used. `forget_track` (a frame without a measured path) keeps d but starts the next
    difference afresh; `reset` forgets d: a new run, or a stop.
    """

    def __init__(self, time_constant: float, limit: float, max_lateral_speed: float) -> None:
        self.time_constant = time_constant
        self.limit = limit
        self.max_lateral_speed = max_lateral_speed
        self.reset()

    def reset(self) -> None:
        """Forget the drift and the last measurement."""
        self.drift = 0.0
        self.forget_track()

    def forget_track(self) -> None:
        """Keep the drift, but take the next measurement as the first of a new track."""
        self._last: tuple[float, float] | None = None

    def update(self, offset: float, heading: float, speed: float, stamp: float) -> float:
        """One measurement: `offset` (m, the robot left of its path > 0), `heading` (rad, the robot
        turned left of its path > 0), `speed` (m/s, commanded over the step) at `stamp` (s).
        Returns the drift estimate (m/s)."""
        last = self._last
        if last is not None and stamp <= last[0]:
            return self.drift  # no time has passed: nothing to difference
        self._last = (stamp, offset)
        if last is None or stamp - last[0] > 1.0:
            return self.drift
        lateral_speed = (offset - last[1]) / (stamp - last[0])
        if abs(lateral_speed) > self.max_lateral_speed:
            return self.drift
        innovation = lateral_speed - speed * math.sin(heading) - self.drift
        gain = min(1.0, (stamp - last[0]) / self.time_constant)
        self.drift = clip(self.drift + gain * innovation, -self.limit, self.limit)
        return self.drift


class ClampedIntegral:
    """The time integral of a measurement, with dt the difference of the measurements' stamps,
    clamped to ±`limit` (anti-windup).

    SegCorridor's `centre_hold` law can integrate the centreline's offset so that a steady sideways
    drift (a skid-steer robot creeping downhill) leaves no standing offset. The clamp bounds what a start
    transient or a long bend can wind up; a step more than `max_step` seconds after the previous
    one (the robot stood, or the path was lost) is not integrated; `forget_track` (a frame without a
    measured path) keeps the sum but starts the next step afresh; `reset` forgets it (a new run, a
    stop).
    """

    def __init__(self, limit: float, max_step: float = 1.0) -> None:
        self.limit = limit
        self.max_step = max_step
        self.reset()

    def reset(self) -> None:
        """Forget the sum and the last stamp."""
        self.value = 0.0
        self.forget_track()

    def forget_track(self) -> None:
        """Keep the sum, but take the next measurement as the first of a new track."""
        self._last_stamp: float | None = None

    def update(self, measurement: float, stamp: float) -> float:
        """Add `measurement` over the time since the previous stamp; returns the clamped sum."""
        last, self._last_stamp = self._last_stamp, stamp
        if last is not None and 0.0 < stamp - last <= self.max_step:
            self.value = clip(self.value + measurement * (stamp - last), -self.limit, self.limit)
        elif last is not None and stamp <= last:
            self._last_stamp = last  # no time has passed: nothing to add
        return self.value
