"""The control pieces every navigator shares: the command it returns, the limits it clips to and
the paper's EMA that smooths it.

They are written once so that the four methods cannot drift apart: SegCorridor's command is
smoothed by exactly the EMA of SegMin, SegMinD and SegZeros (Navone et al., section 2:
y_t = (1 - lambda) y_{t-1} + lambda u_t), and a stop is the same stop whoever issues it.
numpy only (part of the bare robot install).
"""

from __future__ import annotations

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


class OffsetIntegrator:
    """The integral term of a path-following law: `gain` times the time integral of the lateral
    offset (metres, > 0: the path lies to the robot's left), added to the yaw rate.

    A proportional-derivative law (pure pursuit is one) balances a steady sideways disturbance
    only with a standing offset: a robot that creeps downhill across a slope, or tracks that turn
    less than commanded on rough ground, hold the row off centre. The integral grows until it
    cancels the disturbance. Anti-windup, so that it never drives the robot into a row:

    - the term is clamped to +-`limit` rad/s (the integral stops growing there);
    - offsets beyond `band` metres are not integrated: they are transients (the start, a bend
      seen late, a wrong fit), which the proportional part removes, and integrating them would
      overshoot by as much afterwards;
    - nothing is integrated while the command is saturated towards the offset.

    The time step is the difference of the commands' stamps (seconds): never an assumed rate. The
    first update after `reset`, and one whose stamp is not after the previous, integrate nothing;
    an update without an offset (no path seen) only moves the stamp on, so the time without a
    path is not integrated either. Its state is one run's: `reset` forgets it.
    """

    def __init__(self, gain: float, limit: float, band: float) -> None:
        self.gain = gain
        self.limit = limit
        self.band = band
        self.reset()

    def reset(self) -> None:
        """Forget the integral and the last stamp."""
        self.integral = 0.0
        self._stamp: float | None = None

    @property
    def term(self) -> float:
        """The yaw rate (rad/s) the integral adds now."""
        return self.gain * self.integral

    def update(self, offset: float | None, stamp: float, saturated: bool = False) -> float:
        """Integrate `offset` over the time since the previous stamp (unless an anti-windup rule
        holds it) and return the term; `saturated`: the command is at its limit towards the offset."""
        previous, self._stamp = self._stamp, stamp if self._stamp is None else max(self._stamp, stamp)
        if offset is None or previous is None or stamp <= previous or saturated or abs(offset) > self.band:
            return self.term
        if self.gain > 0:
            bound = self.limit / self.gain
            self.integral = clip(self.integral + offset * (stamp - previous), -bound, bound)
        return self.term
