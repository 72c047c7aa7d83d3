"""Phase-locking the command timer to the runtime's command deadlines (`publish_on_timer`).

A timer at `command_hz` with an arbitrary phase publishes each fresh command up to a whole
period after it was computed (100 ms on average at 5 Hz). The runtime computes its commands on a
fixed grid of image-stamp times (`RowFollower`: one every 1 / command_hz from the first frame),
each when the frame at that deadline has been segmented. So the timer can tick on the same grid,
shifted by how long a command takes to be ready: the period stays regular (its jitter is the
thread's wake-up delay plus at most `slew_s`) and a command waits only for the margin.

`lead` is the node clock when a fresh command was ready minus its deadline in stamp time: the
transport, the queue and the step, plus any constant offset between the camera's clock and the
node's, which the lock absorbs. The timer aims `quantile` of recent leads plus `margin_s` past
each deadline; it moves by at most `slew_s` a tick (a jump only when it is more than
`relock_share` of a period off: at start-up, or when the camera restarts), so a slow step now
and then does not drag the period. A command not ready at its tick goes out when it is ready
(`FollowerCore`), without pacing the timer.
"""

from __future__ import annotations

from collections import deque

import numpy as np

WINDOW = 50  # leads kept: 10 s of commands at 5 Hz
QUANTILE = 0.9  # the tick waits for this share of recent commands
MARGIN_S = 0.001  # past that quantile
SLEW_S = 0.001  # the most a tick moves from the nominal period once locked
RELOCK_SHARE = 0.2  # an error larger than this share of the period re-locks at once


class CommandPhase:
    """Where the next tick of a `period_s` timer should fall (see the module docstring)."""

    def __init__(self, period_s: float) -> None:
        self.period_s = float(period_s)
        self._leads: deque[float] = deque(maxlen=WINDOW)
        self._deadline: float | None = None  # the newest command deadline seen, stamp time

    def observe(self, deadline: float, ready: float) -> None:
        """A fresh command for the deadline `deadline` (stamp time) was ready at `ready` (node clock)."""
        self._leads.append(ready - deadline)
        self._deadline = deadline

    def offset(self) -> float | None:
        """How long after a deadline the tick aims to fall (node clock minus stamp time), or None."""
        if not self._leads:
            return None
        return float(np.quantile(np.fromiter(self._leads, dtype=float), QUANTILE)) + MARGIN_S

    def next_tick(self, previous: float) -> float:
        """The tick after the one at `previous` (node clock, seconds)."""
        nominal = previous + self.period_s
        offset = self.offset()
        if offset is None or self._deadline is None:
            return nominal  # free-running until the first fresh command
        grid = self._deadline + offset  # a tick on the runtime's grid
        target = grid + round((nominal - grid) / self.period_s) * self.period_s
        error = target - nominal
        if abs(error) > RELOCK_SHARE * self.period_s:
            return target if target > previous + 0.5 * self.period_s else target + self.period_s
        return nominal + max(-SLEW_S, min(SLEW_S, error))
