"""Phase-locking the command timer to the runtime's command deadlines (`publish_on_timer`).

A timer at `command_hz` with an arbitrary phase publishes each fresh command up to a whole
period after it was computed (100 ms on average at 5 Hz). The runtime computes its commands on a
fixed grid of image-stamp times (`RowFollower`: one every 1 / command_hz from the first frame),
each when the frame at that deadline has been segmented. So the timer can tick on the same grid,
shifted by how long a command takes to be ready: the period stays regular (its jitter is the
thread's wake-up delay plus at most SLEW_S) and a command waits only for the margin.

A command's lead splits in two. The frame's delay: its stamp minus the deadline (a command is
computed at the first frame at or after its deadline; a 30 Hz camera puts every sixth frame on
a 5 Hz grid, and a frame stamped a hair early moves the command to the next frame, 33 ms later).
And its handling: the node clock when the command was ready minus the frame's stamp (transport,
queue and step, plus any constant offset between the camera's clock and the node's, which the
lock absorbs). The timer aims at DELAY_QUANTILE of recent delays (the usual, on-time frame)
plus HANDLING_QUANTILE of recent handling times plus MARGIN_S past each deadline; a command
from a late frame then goes out at once instead of holding every tick back by a frame. It jumps onto that grid once, after MIN_LEADS commands, and again only when the
runtime's grid moves (a restart after a frame timeout, new parameters); otherwise it moves by at
most SLEW_S a tick, so a slow step now and then does not drag the period. A command that misses
its tick goes out when it is ready (`FollowerCore`), without pacing the timer.
"""

from __future__ import annotations

from collections import deque

import numpy as np

WINDOW = 50  # leads kept: 10 s of commands at 5 Hz
MIN_LEADS = 10  # commands seen before the first lock (2 s at 5 Hz): one slow first step must not set the phase
DELAY_QUANTILE = 0.1  # the frame delay the tick expects: the on-time frames'
HANDLING_QUANTILE = 0.9  # the tick waits for this share of recent handling times
MARGIN_S = 0.001  # past that quantile
SLEW_S = 0.001  # the most a tick moves from the nominal period once locked
GRID_TOLERANCE_S = 0.001  # a deadline further than this from the locked grid means the runtime restarted


class CommandPhase:
    """Where the next tick of a `period_s` timer should fall (see the module docstring)."""

    def __init__(self, period_s: float) -> None:
        self.period_s = float(period_s)
        self._delays: deque[float] = deque(maxlen=WINDOW)
        self._handling: deque[float] = deque(maxlen=WINDOW)
        self._deadline: float | None = None  # the newest command deadline seen, stamp time
        self._jump = True  # the next tick may jump onto the grid: not locked yet, or the grid moved

    def observe(self, deadline: float, frame_t: float, ready: float) -> None:
        """A fresh command for the deadline `deadline`, computed at the frame stamped `frame_t` (both
        stamp time), was ready at `ready` (node clock)."""
        if self._deadline is not None:
            periods = (deadline - self._deadline) / self.period_s
            if abs(periods - round(periods)) * self.period_s > GRID_TOLERANCE_S:
                self._jump = True  # the runtime restarted (a frame timeout, new parameters): a new grid
        self._delays.append(frame_t - deadline)
        self._handling.append(ready - frame_t)
        self._deadline = deadline

    def offset(self) -> float | None:
        """How long after a deadline the tick aims to fall (node clock minus stamp time), or None
        before MIN_LEADS commands."""
        if len(self._delays) < MIN_LEADS:
            return None
        delay = np.quantile(np.fromiter(self._delays, dtype=float), DELAY_QUANTILE)
        return float(delay + np.quantile(np.fromiter(self._handling, dtype=float), HANDLING_QUANTILE)) + MARGIN_S

    def next_tick(self, previous: float) -> float:
        """The tick after the one at `previous` (node clock, seconds)."""
        nominal = previous + self.period_s
        offset = self.offset()
        if offset is None or self._deadline is None:
            return nominal  # free-running until the lock
        grid = self._deadline + offset  # a tick on the runtime's grid
        target = grid + round((nominal - grid) / self.period_s) * self.period_s
        if self._jump:  # one irregular period to lock, never a period under half the nominal one
            self._jump = False
            return target if target > previous + 0.5 * self.period_s else target + self.period_s
        return nominal + max(-SLEW_S, min(SLEW_S, target - nominal))
