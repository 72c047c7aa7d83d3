"""Colour and depth frames paired by header stamp: the one rule for bag replay and the ROS 2 node.

A RealSense publishes colour and aligned depth on two topics whose stamps differ by a few
milliseconds (or not at all, as in segmin's simulated bags). Each stream comes in stamp order;
a colour frame is paired with the depth frame nearest to it in time within `slop` seconds
(of those received: keep `slop` under half a frame period and the first within it is the
nearest), and a frame that can have no partner any more (the other stream has moved past it) is dropped
and counted. Pure Python, no ROS: both the bag reader and the node feed it.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any


@dataclass
class Stamped:
    """One frame of one stream: its header stamp (s) and what the caller keeps with it."""

    t: float
    item: Any


class StampOrderError(ValueError):
    """A stream's stamp is not after the one before it."""


class StampPairer:
    """Merges the colour and depth streams into (colour, depth) pairs, in stamp order.

    `max_pending` bounds what waits for a partner (a live node must not queue frames behind a
    stalled topic); the oldest is dropped first.
    """

    def __init__(self, slop: float, *, max_pending: int = 8) -> None:
        if not slop >= 0:
            raise ValueError(f"slop must be a number of seconds >= 0, got {slop!r}")
        self.slop = float(slop)
        self.max_pending = max_pending
        self._colour: deque[Stamped] = deque()
        self._depth: deque[Stamped] = deque()
        self._last = {"colour": -float("inf"), "depth": -float("inf")}
        self.dropped_colour = 0
        self.dropped_depth = 0

    def add_colour(self, t: float, item: Any) -> list[tuple[Stamped, Stamped]]:
        """Take a colour frame; returns the pairs it completes."""
        return self._add("colour", self._colour, t, item)

    def add_depth(self, t: float, item: Any) -> list[tuple[Stamped, Stamped]]:
        """Take a depth frame; returns the pairs it completes."""
        return self._add("depth", self._depth, t, item)

    def finish(self) -> None:
        """The streams ended: what still waits has no partner."""
        self.dropped_colour += len(self._colour)
        self.dropped_depth += len(self._depth)
        self._colour.clear()
        self._depth.clear()

    def _add(self, stream: str, queue: deque[Stamped], t: float, item: Any) -> list[tuple[Stamped, Stamped]]:
        if not t > self._last[stream]:
            raise StampOrderError(
                f"stamp {t:.9f} s is not after the previous {stream} frame's ({self._last[stream]:.9f} s)"
            )
        self._last[stream] = t
        queue.append(Stamped(t, item))
        pairs = self._match()
        while len(self._colour) > self.max_pending:
            self._colour.popleft()
            self.dropped_colour += 1
        while len(self._depth) > self.max_pending:
            self._depth.popleft()
            self.dropped_depth += 1
        return pairs

    def _match(self) -> list[tuple[Stamped, Stamped]]:
        pairs = []
        colour, depth = self._colour, self._depth
        while colour and depth:
            c, d = colour[0], depth[0]
            if abs(c.t - d.t) <= self.slop + 1e-12:
                # A later frame of either stream may be nearer still; it then wins.
                if len(depth) > 1 and abs(depth[1].t - c.t) < abs(d.t - c.t):
                    depth.popleft()
                    self.dropped_depth += 1
                elif len(colour) > 1 and abs(colour[1].t - d.t) < abs(c.t - d.t):
                    colour.popleft()
                    self.dropped_colour += 1
                else:
                    pairs.append((colour.popleft(), depth.popleft()))
            elif c.t < d.t:  # every depth frame to come is later still: c has no partner
                colour.popleft()
                self.dropped_colour += 1
            else:
                depth.popleft()
                self.dropped_depth += 1
        return pairs
