"""The node's own timing of its commands, measured where they happen.

- Latency: from the moment DDS handed the node an image (`received_timestamp` of the message
  info, system clock) to the moment the command computed from it was first published. A
  receiver of `cmd_vel` would add its own transport and executor delays; this is the node's share.
- Period: between consecutive publications that set the command rate (fresh commands when they
  go out at once; every tick with `publish_on_timer`) while driving, i.e. both answering an
  image (a stop for want of frames, at start-up or a stalled camera, breaks the chain), on the
  monotonic clock at publication, and its jitter |period - 1 / command_hz|.

The diagnostics report both; `segmin bench ros2` prints them beside what its receiver saw. No
ROS import.
"""

from __future__ import annotations

import threading
from collections import OrderedDict, deque

import numpy as np

KEEP = 2000  # samples kept: 400 s of commands at 5 Hz (a bench runs 60 s)
RECEPTIONS_KEPT = 64  # images awaiting their command: two seconds of a 30 Hz camera


class CommandTiming:
    """Reception times of images and publication times of commands; thread-safe (two callback groups)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._received: OrderedDict[int, int] = OrderedDict()  # image stamp ns -> reception ns
        self.latency_s: deque[float] = deque(maxlen=KEEP)
        self.period_s: deque[float] = deque(maxlen=KEEP)
        self._paced_at: float | None = None  # monotonic time of the latest paced publication while driving

    def image_received(self, stamp_ns: int, received_ns: int) -> None:
        with self._lock:
            self._received[stamp_ns] = received_ns
            while len(self._received) > RECEPTIONS_KEPT:
                self._received.popitem(last=False)

    def published(self, stamp_ns: int | None, now_ns: int, monotonic_s: float, paced: bool) -> None:
        """A command went out: `stamp_ns` is its image's stamp (None: a stop for want of frames);
        `paced`: it sets the command rate."""
        with self._lock:
            received = self._received.pop(stamp_ns, None) if stamp_ns is not None else None
            if received is not None:
                self.latency_s.append((now_ns - received) * 1e-9)
            if not paced:
                return
            if stamp_ns is None:
                self._paced_at = None
                return
            if self._paced_at is not None:
                self.period_s.append(monotonic_s - self._paced_at)
            self._paced_at = monotonic_s

    def summary(self, command_hz: int) -> dict[str, str]:
        """Key -> value for the diagnostics (milliseconds)."""
        with self._lock:
            latency = np.asarray(self.latency_s, dtype=float)
            periods = np.asarray(self.period_s, dtype=float)
        jitter = np.abs(periods - 1.0 / command_hz)
        return {
            "latency image received to command published median ms": _ms(latency, 50),
            "latency image received to command published p95 ms": _ms(latency, 95),
            "command period median ms": _ms(periods, 50),
            "command period jitter p99 ms": _ms(jitter, 99),
            "command periods timed": str(periods.size),
        }


def _ms(values: np.ndarray, percentile: float) -> str:
    return f"{1e3 * np.percentile(values, percentile):.2f}" if values.size else "-"
