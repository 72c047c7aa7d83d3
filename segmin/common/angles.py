"""Angle wrapping, shared by the world specs (row turns), the robot model and the metrics.

One formula everywhere, so a heading error in the metrics is the same number the robot and the
world generator would compute for the same two angles.
"""

from __future__ import annotations

import math
from typing import overload

import numpy as np


@overload
def wrap_angle(angle: float) -> float: ...
@overload
def wrap_angle(angle: np.ndarray) -> np.ndarray: ...


def wrap_angle(angle: float | np.ndarray) -> float | np.ndarray:
    """`angle` (radians) wrapped to [-pi, pi); a float stays a float (the robot steps per call)."""
    if isinstance(angle, (int, float)):
        return (angle + math.pi) % (2.0 * math.pi) - math.pi
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi
