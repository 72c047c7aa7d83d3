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
