"""SegCorridor's settings (`CorridorConfig`), each checked when the config is built.

The roles of the settings: the algorithm in docs/reference/equations.md (SegCorridor); the keys
with their defaults: docs/reference/configs.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

from ..checks import check_depth_threshold, check_positive

_DRIFT_OBSERVER_REMOVED = (
    "the drift_observer controller measured worse than pure pursuit in bends (docs/results/history/segcorridor.md)"
)
# pursuit: pure pursuit alone; centre_hold: pure pursuit on a short lookahead plus heading damping,
# tuned for the skid-steer robot (corridor.steering)
CONTROLLERS = ("pursuit", "centre_hold")
ROOF_BIN = 0.25  # metres: the lateral bins of the roof-opening test


@dataclass(frozen=True)
class CorridorConfig:
    """SegCorridor's parameters (their roles: the package's docstring and the equations); distances in metres.

    `depth_threshold` is the fallback's (SegMinD's) depth cut and has no default, as in
    `NavigatorConfig`. The defaults were chosen on the five test fields (docs/nav_eval.md).
    """

    depth_threshold: float
    fuse_frames: int = 3
    x_min: float = 0.5
    x_max: float = 8.0
    h_min: float = 0.1
    h_max: float = 4.0
    max_lateral: float = 3.5
    roof_share: float = 0.6
    roof_min_height: float = 1.5
    stride: int = 3
    min_points: int = 30
    max_points: int = 600
    min_span: float = 1.0
    trim: float = 2.5
    trim_iterations: int = 2
    degree: int = 2
    significance: float = 3.0
    width_memory: float = 0.2
    centre_memory: float = 0.5
    lookahead: float = 2.5
    roof_opening: float = 0.5
    roof_opening_reach: float = 2.5
    trunk_h_min: float = 0.3
    trunk_h_max: float = 1.3
    trunk_x_max: float = 12.0
    trunk_stride: int = 2
    trunk_min_points: int = 15
    trunk_max_lateral: float = 6.0
    trunk_max_excess_green: float = 10.0
    v_max: float = 0.5
    omega_max: float = 1.0
    ema_lambda: float = 0.5
    controller: str = "pursuit"
    hold_lookahead: float = 1.0
    hold_heading_gain: float = 0.6
    hold_slope_drift: float = 0.0
    row_start_max: float = math.inf
    method: str = field(default="segcorridor", init=False)
    # Settings that existed and lost (docs/results/history/segcorridor.md): a config that still
    # sets one is told so in one line (segmin.common.config.from_dict), not just "unknown key".
    REMOVED_KEYS: ClassVar[Mapping[str, str]] = {
        "drift_time": _DRIFT_OBSERVER_REMOVED,
        "drift_limit": _DRIFT_OBSERVER_REMOVED,
        "heading_gain": _DRIFT_OBSERVER_REMOVED,
        "hold_integral_time": "centre_hold's offset integral raised the pear field's error from 0.028 to 0.040-0.053 m",
        "trunks": "the trunk mode is always on (high trees 0.311 -> 0.053 m)",
    }

    def __post_init__(self) -> None:
        check_depth_threshold(self.depth_threshold)
        if self.degree not in (1, 2):
            raise ValueError(f"corridor.degree must be 1 (straight rows) or 2 (bends), got {self.degree!r}")
        for name in (
            "fuse_frames",
            "stride",
            "min_points",
            "max_points",
            "trim_iterations",
            "trunk_stride",
            "trunk_min_points",
        ):
            value = getattr(self, name)
            low = 0 if name == "trim_iterations" else 1
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"corridor.{name} must be an integer >= {low}, got {value!r}")
        for name in (
            "x_max",
            "h_max",
            "max_lateral",
            "roof_min_height",
            "min_span",
            "trim",
            "lookahead",
            "v_max",
            "omega_max",
            "trunk_x_max",
            "trunk_h_max",
            "trunk_max_lateral",
            "roof_opening_reach",
            "hold_lookahead",
        ):
            check_positive(f"corridor.{name}", getattr(self, name))
        start_max = self.row_start_max
        if isinstance(start_max, bool) or not isinstance(start_max, (int, float)) or not start_max > self.x_min:
            raise ValueError(
                f"corridor.row_start_max must be a number above corridor.x_min ({self.x_min}) "
                f"(inf: every row is fitted), got {self.row_start_max!r}"
            )
        self._check_controller()
        if not (math.isfinite(self.significance) and self.significance >= 0.0):
            raise ValueError(f"corridor.significance must be a finite number >= 0, got {self.significance!r}")
        for name in ("x_min", "h_min", "trunk_h_min", "trunk_max_excess_green"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"corridor.{name} must be finite, got {getattr(self, name)!r}")
        if self.trunk_h_min >= self.trunk_h_max:
            raise ValueError(
                f"corridor.trunk_h_min ({self.trunk_h_min}) must be below corridor.trunk_h_max ({self.trunk_h_max})"
            )
        if self.roof_opening_reach < ROOF_BIN:
            raise ValueError(
                f"corridor.roof_opening_reach must be at least {ROOF_BIN} m (one bin), got {self.roof_opening_reach!r}"
            )
        if not (math.isfinite(self.roof_opening) and 0.0 <= self.roof_opening <= 2 * self.roof_opening_reach):
            raise ValueError(
                f"corridor.roof_opening must be within [0, 2 x roof_opening_reach] = "
                f"[0, {2 * self.roof_opening_reach}] m, got {self.roof_opening!r}"
            )
        if self.x_min >= self.trunk_x_max:
            raise ValueError(f"corridor.x_min ({self.x_min}) must be below corridor.trunk_x_max ({self.trunk_x_max})")
        if self.x_min >= self.x_max:
            raise ValueError(f"corridor.x_min ({self.x_min}) must be below corridor.x_max ({self.x_max})")
        if self.h_min >= self.h_max:
            raise ValueError(f"corridor.h_min ({self.h_min}) must be below corridor.h_max ({self.h_max})")
        self._check_rows_can_be_seen()
        for name in ("ema_lambda", "width_memory", "centre_memory", "roof_share"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ValueError(f"corridor.{name} must be in (0, 1], got {getattr(self, name)!r}")

    def _check_controller(self) -> None:
        """The steering law's name, centre_hold's heading gain (0: no heading damping) and its
        slope-drift coefficient (0: no slope feedforward)."""
        if self.controller == "drift_observer":
            raise ValueError(
                f"corridor.controller drift_observer was removed: {_DRIFT_OBSERVER_REMOVED}; use centre_hold"
            )
        if self.controller not in CONTROLLERS:
            raise ValueError(f"corridor.controller must be one of {', '.join(CONTROLLERS)}, got {self.controller!r}")
        for name in ("hold_heading_gain", "hold_slope_drift"):
            gain = getattr(self, name)
            if isinstance(gain, bool) or not isinstance(gain, (int, float)) or not (math.isfinite(gain) and gain >= 0):
                raise ValueError(f"corridor.{name} must be a finite number >= 0, got {gain!r}")

    def _check_rows_can_be_seen(self) -> None:
        """Limits that each pass alone but together leave no row ever seen: every frame would
        end in the fallback, and SegCorridor would silently drive as SegMinD."""
        if 2 * self.min_points > self.max_points:
            raise ValueError(
                f"corridor.min_points ({self.min_points}) is more than half of corridor.max_points "
                f"({self.max_points}): both rows need min_points each of the at most max_points points kept"
            )
        if self.min_span > self.x_max - self.x_min:
            raise ValueError(
                f"corridor.min_span ({self.min_span}) is longer than the range corridor.x_min..x_max "
                f"({self.x_min}..{self.x_max}) that a row's points span at most"
            )
        if self.roof_min_height <= self.h_min:
            raise ValueError(
                f"corridor.roof_min_height ({self.roof_min_height}) must be above corridor.h_min ({self.h_min}): "
                "every kept point would be roof, and no row would be fitted"
            )
