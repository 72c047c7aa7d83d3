"""Checks of the numbers that configure the navigators and the camera, each naming the setting.

Shared by the paper's navigator, SegCorridor and the camera geometry, so a bad value reads the
same wherever it is set.
"""

from __future__ import annotations

import math
import numbers


def check_positive(name: str, value: float) -> None:
    """ValueError naming `name` unless `value` is a finite number > 0 (numpy scalars included)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def check_depth_threshold(value: float) -> None:
    """ValueError unless the depth threshold is a finite number of metres > 0.

    numbers.Real, not (int, float): a threshold read from numpy (np.float32) is a fine number.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"depth_threshold must be a finite number of metres > 0, got {value!r}")
