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

# The estimator's inner settings: fixed, not configured. Each was chosen on the five test fields
# and no shipped config or robot default sets another (docs/results/history/segcorridor.md); their
# roles are in docs/reference/equations.md (SegCorridor). A config that still sets one is told so.
MAX_LATERAL = 3.5  # m: vegetation points kept within this of the split line (before the width is known)
ROOF_SHARE = 0.6  # share of points above ROOF_MIN_HEIGHT that makes the canopy a roof
ROOF_MIN_HEIGHT = 1.5  # m: a point above this is roof
MIN_SPAN = 1.0  # m: a row is seen when its points span this far along x
TRIM_ITERATIONS = 2  # rounds of trimming points far from their row's curve, then refitting
SIGNIFICANCE = 3.0  # standard errors both rows' curvature must exceed for the quadratic
WIDTH_MEMORY = 0.2  # weight of a new corridor width in its running estimate
ROOF_OPENING_REACH = 2.5  # m: how far to each side the roof's opening is looked for
TRUNK_H_MIN, TRUNK_H_MAX = 0.3, 1.3  # m: the height band where trunks and posts are looked for
TRUNK_X_MAX = 12.0  # m: trunks and posts are looked for up to this far ahead
TRUNK_STRIDE = 2  # px: every n-th pixel (both directions) of the trunk search
TRUNK_MAX_LATERAL = 6.0  # m: trunk points kept within this of the split line (before the width is known)
TRUNK_MAX_EXCESS_GREEN = 10.0  # a trunk pixel is not green: 2G - R - B at most this
GROUND_BANDS = (1.0, 0.3, 0.15)  # m: the ground plane's rounds, each fitted to the points this near the last
GROUND_MIN_POINTS = 30  # fewer non-vegetation points near the ground: the robot's own plane is the ground
_FIXED = {
    "max_lateral": MAX_LATERAL,
    "roof_share": ROOF_SHARE,
    "roof_min_height": ROOF_MIN_HEIGHT,
    "min_span": MIN_SPAN,
    "trim_iterations": TRIM_ITERATIONS,
    "significance": SIGNIFICANCE,
    "width_memory": WIDTH_MEMORY,
    "roof_opening_reach": ROOF_OPENING_REACH,
    "trunk_h_min": TRUNK_H_MIN,
    "trunk_h_max": TRUNK_H_MAX,
    "trunk_x_max": TRUNK_X_MAX,
    "trunk_stride": TRUNK_STRIDE,
    "trunk_max_lateral": TRUNK_MAX_LATERAL,
    "trunk_max_excess_green": TRUNK_MAX_EXCESS_GREEN,
}


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
    stride: int = 3
    min_points: int = 30
    max_points: int = 600
    trim: float = 2.5
    degree: int = 2
    centre_memory: float = 0.5
    lookahead: float = 2.5
    roof_opening: float = 0.5
    trunk_min_points: int = 15
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
        **{key: f"now fixed at {value} (segmin.nav_eval.runtime.corridor.config)" for key, value in _FIXED.items()},
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
            "trunk_min_points",
        ):
            value = getattr(self, name)
            low = 1
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"corridor.{name} must be an integer >= {low}, got {value!r}")
        for name in (
            "x_max",
            "h_max",
            "trim",
            "lookahead",
            "v_max",
            "omega_max",
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
        for name in ("x_min", "h_min"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"corridor.{name} must be finite, got {getattr(self, name)!r}")
        if not (math.isfinite(self.roof_opening) and 0.0 <= self.roof_opening <= 2 * ROOF_OPENING_REACH):
            raise ValueError(
                f"corridor.roof_opening must be within [0, {2 * ROOF_OPENING_REACH}] m (twice the "
                f"{ROOF_OPENING_REACH} m searched each side), got {self.roof_opening!r}"
            )
        if self.x_min >= TRUNK_X_MAX:
            raise ValueError(
                f"corridor.x_min ({self.x_min}) must be below {TRUNK_X_MAX} m, where trunks are looked for"
            )
        if self.x_min >= self.x_max:
            raise ValueError(f"corridor.x_min ({self.x_min}) must be below corridor.x_max ({self.x_max})")
        if self.h_min >= self.h_max:
            raise ValueError(f"corridor.h_min ({self.h_min}) must be below corridor.h_max ({self.h_max})")
        self._check_rows_can_be_seen()
        for name in ("ema_lambda", "centre_memory"):
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
        if self.x_max - self.x_min < MIN_SPAN:
            raise ValueError(
                f"corridor.x_min..x_max ({self.x_min}..{self.x_max}) is shorter than the {MIN_SPAN} m "
                "a row's points must span to be seen"
            )
        if self.h_min >= ROOF_MIN_HEIGHT:
            raise ValueError(
                f"corridor.h_min ({self.h_min}) must be below {ROOF_MIN_HEIGHT} m, where the roof starts: "
                "every kept point would be roof, and no row would be fitted"
            )
