"""SegCorridor: a fourth navigator, beyond the paper, that steers along the corridor's centreline.

SegMin and SegMinD steer to the image column with the least near vegetation. That column is
the far end of the visible corridor, so the robot cuts bends, and under merged crowns the
column minimum sits wherever the canopy is thinnest. SegCorridor uses what the paper's methods
throw away: the depth of each vegetation pixel and the known camera, which place the pixel in
the robot frame. From there:

1. **Back-projection.** Pixel (u, v) with planar depth z is, in the camera frame (x right,
   y down, z forward), P_c = z ((u - c_x) / f_x, (v - c_y) / f_y, 1). The camera sits `forward`
   ahead of the robot centre, `height` above the ground, pitched up by theta; in the robot frame
   (x forward, y left, h up):

       x = forward + z (cos theta + Y sin theta),   y = -z X,   h = height + z (sin theta - Y cos theta)

   with X = (u - c_x) / f_x and Y = (v - c_y) / f_y. When the robot's IMU gives its roll phi
   and pitch psi (REP 103), the point is levelled, (x, y, h) <- R_y(psi) R_x(phi) (x, y, h):
   rows stand along gravity, not along the robot's up axis, and on rough ground a roll of
   2 degrees moves a crown 1.5 m above the camera by 5 cm. Only pixels of the fused mask with valid
   depth, `x_min <= x <= x_max`, `h_min <= h <= h_max` (ground false positives and the crowns
   above the robot are dropped) and within `max_lateral` of the split line and within the
   running corridor width w of it (the next rows stand at 1.5 w; before w is known, within 1.5 x
   the free width between the nearest walls, each side's 10th percentile distance) are kept; every
   `stride`-th pixel in both directions, thinned evenly to at most `max_points`, is enough for
   a line fit and keeps the step cheap.
2. **Two rows.** The points left of the split line are the left row, the others the right row.
   The split line is the previous frame's centreline; without one (start, after a fallback) it
   is the ray through SegMinD's target column (found on the strided pixel grid), which points
   into the free corridor even with a large heading error.
3. **Robust parallel fit of the rows.** The rows are parallel: y = c_0L + c_1 x + c_2 x^2 and
   y = c_0R + c_1 x + c_2 x^2, one least-squares fit of both rows' points (design columns
   [1, 0, x, x^2] for a left point, [0, 1, x, x^2] for a right one), then `trim_iterations`
   rounds that drop points further than `trim` robust standard deviations (1.4826 MAD) from
   their row's curve and refit: gaps, leaves hanging into the row and a stray weed do not bend
   the corridor. A straight line over 0.5-8 m is a chord of a bend and sits inside it at the
   lookahead, so with `degree` 2 (the default) the quadratic is used, but only when the bend is
   seen in both rows: each row first gets its own c_2 (columns x^2 [left], x^2 [right]), and
   unless both exceed `significance` standard errors with the same sign the rows are refitted
   as lines (per-row quadratics left a straight vineyard with 15 % missing plants through a
   gap and collided at 1.6 m row spacing). A row is *seen* when at least `min_points` points
   span `min_span` metres in x and `min_points` survive the trimming. With `row_start_max` set
   (default inf: off), a row whose points start (10th percentile of x) beyond it while the other
   row's start nearer is left out (one_side below): through a run of missing trees its line,
   extrapolated back over metres of a bend, moves the centre by tens of centimetres.
4. **Centreline.** Both rows seen: ((c_0L + c_0R) / 2, c_1, c_2), and the corridor width
   c_0L - c_0R updates a running estimate. One row seen: that line moved by half the running width towards
   the corridor. No row seen, or no width yet: SegMinD's column and control law (the fallback).
   Under a roof, when at least `roof_share` of the vegetation points in range (and `min_points`)
   lie above `roof_min_height` (pergola canopy, merged crowns: 0.84-1.00 of the points; vertical
   vine walls and pear hedges 0.20-0.33), the rows are not walls: see 4b.
   Between commands the robot moves about 0.1 m, so the new centreline is averaged with the
   previous one (weight `centre_memory` on the new), which halves the frame-to-frame noise that
   gaps and single trunks put into the fit.
4b. **Under a roof: the opening, or the trunks.** The roof points' lateral positions y (along the
   robot, not the split line: no split needs searching under a pergola), binned in 0.25 m within
   `roof_opening_reach`, show whether the roof has an opening along the corridor (the widest run
   of bins with fewer than 2 points). An opening of at least
   `roof_opening` (a pergola's free band: 0.75-1.25 m on the test field) is what SegMinD's
   column follows, so SegMinD steers (the fallback). A closed canopy (merged crowns: 0-0.25 m)
   has no such column, and the rows are found on their trunks and posts instead: the pixels that
   are not vegetation in the fused mask (nor green in the image, when the runtime gives one:
   excess green 2G - R - B <= `trunk_max_excess_green`, so leaves the mask missed do not count),
   every `trunk_stride`-th, back-projected as in 1 (x, y levelled; h in the robot's own frame,
   i.e. above the ground it stands on: on a cross slope the level plane through the robot cuts the
   uphill row's ground) and kept when `x_min <= x <= trunk_x_max` and
   `trunk_h_min <= h <= trunk_h_max` (above the ground's roughness, below the crowns) and within
   `trunk_max_lateral` of the split line (and within the running trunk-to-trunk width of it, once
   known). A trunk or two a side give no reliable heading, so the
   centreline is taken along the robot: y = (median y_L + median y_R) / 2, each side needing
   `trunk_min_points`; the goal is then the middle between the trunks ahead, which also turns a
   heading error out. With one side seen (or both, crossed), the side with more points moved by
   half the running trunk-to-trunk width.
   With neither, SegMinD steers.
5. **Pure pursuit.** The goal point is the centreline at x = `lookahead`: (L, y_L) with
   y_L = c(L). The arc through it has curvature kappa = 2 y_L / (L^2 + y_L^2); the bearing
   alpha = atan2(y_L, L) sets the speed as in the paper, v = v_max (1 - (alpha / alpha_max)^2)
   with alpha_max the half field of view, and omega = v_max kappa, clipped; both are smoothed with the
   paper's EMA.
6. **Centre hold** (`controller` "centre_hold", the law for a skid-steer robot; "pursuit", the
   default, stops at 5). On row fits: pure pursuit to the goal on the short lookahead
   `hold_lookahead`, plus `hold_heading_gain` atan(c_1), and with `hold_slope_drift` k_s > 0
   (default 0: off) (2 v / L + k_h) k_s tan(roll), which points the robot uphill against its creep
   across a slope, from the IMU's roll. The goal's offset c(L) is the best-measured number of the
   fit (c_0 alone is an extrapolation whose error is c_1's times 3-4 m), so the law steers on it
   and takes from c_1 only the extra damping. Trunk mode and the fallback steer as with pursuit.
   Gains and reasons: docs/reference/equations.md.

The paper's three methods are unchanged (nav_eval.navigator). `CorridorNavigator` is a
`MaskNavigator` (nav_eval.runtime.protocols) like the paper's `Navigator`, so the runtime drives
it like the others. It declares what it reads besides the masks (`inputs`): depth, the image
(`rgb`, uint8; without it the trunk test trusts the mask alone), the IMU's attitude and its
camera. Its per-run statistics (`statistics()`) are the shares of commands found on one row, on
the trunks and by the fallback.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from .camera import CameraGeometry
from .checks import check_depth_threshold, check_positive
from .control import Command, CommandSmoother, clip
from .mask_fusion import MaskFusion, validated_mask
from .navigator import (
    Navigator,
    NavigatorConfig,
    _validated_frame,
    control_law,
    histogram_minimum,
    smoothed_histogram,
    target_column,
    validated_attitude,
    validated_rgb,
)
from .protocols import MaskNavigator, NavigatorInputs

MODES = ("both", "one_side", "trunks", "fallback")
_DRIFT_OBSERVER_REMOVED = (
    "the drift_observer controller measured worse than pure pursuit in bends (docs/results/history/segcorridor.md)"
)
# pursuit: pure pursuit alone (step 5); centre_hold: pure pursuit on a short lookahead plus heading
# damping, tuned for the skid-steer robot (step 6)
CONTROLLERS = ("pursuit", "centre_hold")
OBSERVED_MODES = ("both", "one_side")  # the modes whose centreline has a measured heading
ROOF_BIN = 0.25  # metres: the lateral bins of the roof-opening test


@dataclass(frozen=True)
class CorridorConfig:
    """SegCorridor's parameters (module docstring for their role); distances in metres.

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


@dataclass(frozen=True)
class CorridorCommand(Command):
    """A command plus how it was found: `mode` is one of MODES; `centre` the coefficients
    (c_0, c_1[, c_2]) of the centreline y = c_0 + c_1 x (+ c_2 x^2) in the robot frame (None in
    fallback). `histogram` is SegMinD's smoothed histogram in fallback, else empty."""

    mode: str = "fallback"
    centre: tuple[float, ...] | None = None


@dataclass(frozen=True)
class RowsFit:
    """Parallel row curves y = offsets[k] + shape[0] x (+ shape[1] x^2): one offset per row,
    one shape for all; `kept` counts each row's points that survived the trimming."""

    offsets: tuple[float, ...]
    shape: tuple[float, ...]
    kept: tuple[int, ...]

    def row(self, k: int) -> tuple[float, ...]:
        """Coefficients (c_0 up) of row k."""
        return (self.offsets[k], *self.shape)


def fit_parallel_rows(
    sides: Sequence[tuple[np.ndarray, np.ndarray]],
    *,
    trim: float,
    iterations: int,
    degree: int = 1,
    significance: float = 0.0,
) -> RowsFit | None:
    """Robust parallel curves through the points (x, y) of one or more rows: least squares, then
    `iterations` refits without the points further than `trim` robust spreads (1.4826 MAD).

    The rows of a field are parallel, so they share c_1 (and c_2) and differ in c_0 only: the
    heading of the corridor is fitted on the points of every row at once. A bend, though, must
    be seen in every row: with `degree` 2 each row first gets its own c_2, and the quadratic is
    kept only when all of them bend the same way by more than `significance` standard errors;
    otherwise the rows are fitted as lines. A gap in one row through which the next row shows
    bends that row's quadratic alone, and in straight rows the extra freedom only follows noise
    (a straight vineyard with 15 % missing plants was left through a gap with per-row quadratics).
    Returns None with too few points or no spread in x. Coordinates are centred first, so the
    normal equations stay well conditioned. One function: the trim loop and the bend test share
    the design matrix and the per-row bookkeeping, which smaller pieces would pass back and forth.
    """
    counts = [xs.shape[0] for xs, _ in sides]
    if min(counts, default=0) == 0:
        return None
    rows = len(sides)
    bounds = np.array([0, *itertools.accumulate(counts)])
    x = np.concatenate([xs for xs, _ in sides], dtype=np.float64)
    y = np.concatenate([ys for _, ys in sides], dtype=np.float64)
    x_mean = float(x.sum()) / x.shape[0]  # as x.mean(), without its generic machinery
    xc = x - x_mean
    # Design columns: one offset per row, the shared slope, and (degree 2) each row's own x^2,
    # stored one column per array row. The rows' points are consecutive blocks, so each row's
    # columns are filled by slices.
    columns = np.zeros((2 * rows + 1 if degree == 2 else rows + 1, x.shape[0]))
    columns[rows] = xc
    for k in range(rows):
        block = slice(bounds[k], bounds[k + 1])
        columns[k, block] = 1.0
        if degree == 2:
            columns[rows + 1 + k, block] = xc[block] * xc[block]
    start = None
    if degree == 2:
        bent = _trimmed_least_squares(columns, y, trim=trim, iterations=iterations)
        if bent is None:
            return None
        coefficients, keep, standard_errors = bent
        curvatures, errors = coefficients[rows + 1 :], standard_errors[rows + 1 :]
        if np.all(np.abs(curvatures) > significance * errors) and (np.all(curvatures > 0) or np.all(curvatures < 0)):
            joint = np.vstack([columns[: rows + 1], columns[rows + 1 :].sum(axis=0)])  # one shared c_2
            fit = _trimmed_least_squares(joint, y, trim=trim, iterations=0, keep=keep)
            if fit is not None:
                coefficients = fit[0]
                return _rows_fit(
                    coefficients[:rows],
                    float(coefficients[rows]),
                    float(coefficients[-1]),
                    x_mean,
                    keep,
                    bounds,
                    degree,
                )
        start = keep  # the line's trimming starts from the quadratics' inliers: one round fewer
    line = _trimmed_least_squares(columns[: rows + 1], y, trim=trim, iterations=iterations, keep=start)
    if line is None:
        return None
    coefficients, keep, _ = line
    return _rows_fit(coefficients[:rows], float(coefficients[-1]), 0.0, x_mean, keep, bounds, degree)


def _trimmed_least_squares(
    columns: np.ndarray, y: np.ndarray, *, trim: float, iterations: int, keep: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(coefficients, points kept, coefficient standard errors) of the trimmed least-squares fit
    of y on the design `columns` (one column per array row, p x n), or None when the kept points
    do not determine them. The standard errors are of the last refit only, computed once after
    the trimming rounds. `keep` (default: all points) is the set the first round fits.

    A step runs two of these fits, so each round is a handful of whole-array operations: the
    dropped points get weight 0 instead of being copied out, and the conditioning is judged by
    max|N| max|N^-1| of the small p x p normal matrix N (within a factor p^2 of its condition
    number) instead of an SVD."""
    keep = np.ones(y.shape[0], dtype=bool) if keep is None else keep
    weights = keep.astype(float)
    count = int(np.count_nonzero(keep))
    last = None
    for _ in range(iterations + 1):
        if count <= columns.shape[0]:
            break
        weighted = columns * weights
        normal = weighted @ columns.T
        try:
            inverse = np.linalg.inv(normal)
        except np.linalg.LinAlgError:
            break
        # N and N^-1 are positive semi-definite, so their largest entries lie on the diagonals.
        if normal.diagonal().max() * inverse.diagonal().max() > 1e10:
            break  # a row without spread in x, a column without points
        coefficients = inverse @ (weighted @ y)
        residual = np.abs(y - coefficients @ columns)
        last = (coefficients, keep, residual, inverse, count)
        spread = 1.4826 * _median(residual[keep])
        if spread <= 1e-6:  # the points lie on the curves to float32 precision (a micrometre at 8 m)
            break
        new_keep = residual <= trim * spread
        if not (new_keep ^ keep).any():
            break
        keep = new_keep
        weights = keep.astype(float)
        count = int(np.count_nonzero(keep))
    if last is None:
        return None
    coefficients, kept, residual, inverse, count = last
    variance = float(np.sum(residual[kept] ** 2)) / (count - columns.shape[0])
    return coefficients, kept, np.sqrt(np.maximum(variance * np.diag(inverse), 0.0))


def _median(values: np.ndarray) -> float:
    """np.median of a 1-D array without its generic machinery (a third of the fit's time)."""
    middle = values.shape[0] // 2
    if values.shape[0] % 2:
        return float(np.partition(values, middle)[middle])
    part = np.partition(values, (middle - 1, middle))
    return 0.5 * float(part[middle - 1] + part[middle])


def _rows_fit(
    offsets: np.ndarray, c1: float, c2: float, x_mean: float, keep: np.ndarray, bounds: np.ndarray, degree: int
) -> RowsFit:
    """The RowsFit of coefficients fitted in x - x_mean, given back in powers of x; row k's points
    are keep[bounds[k]:bounds[k + 1]]."""
    shape = (c1 - 2.0 * c2 * x_mean, c2) if degree == 2 else (c1,)
    kept = np.add.reduceat(keep.astype(np.int64), bounds[:-1])
    return RowsFit(
        offsets=tuple(float(o - c1 * x_mean + c2 * x_mean * x_mean) for o in offsets),
        shape=shape,
        kept=tuple(int(n) for n in kept),
    )


def polyval(x: np.ndarray | float, c: tuple[float, ...] | np.ndarray) -> np.ndarray | float:
    """c_0 + c_1 x + c_2 x^2 + ... by Horner's rule (numpy's polyval costs more than the fit here)."""
    result = c[-1]
    for coefficient in c[-2::-1]:
        result = result * x + coefficient
    return result


class CorridorNavigator:
    """The stateful SegCorridor navigator (module docstring), a `MaskNavigator`."""

    def __init__(self, config: CorridorConfig, camera: CameraGeometry) -> None:
        self.config = config
        self.camera = camera
        # The trunk test reads the image's colour, the points are levelled with the IMU and
        # placed with the camera; SegMinD's fallback needs depth.
        self.inputs = NavigatorInputs(depth=True, rgb=True, attitude=True, camera=camera)
        self._smoother = CommandSmoother(config.ema_lambda)
        self._fusion = MaskFusion(config.fuse_frames)
        # SegMinD's settings for the fallback's column and control law (the paper's constants
        # beyond the limits and the EMA, which are SegCorridor's).
        self._fallback = NavigatorConfig(
            method="segmind",
            depth_threshold=config.depth_threshold,
            fuse_frames=config.fuse_frames,
            v_max=config.v_max,
            omega_max=config.omega_max,
            ema_lambda=config.ema_lambda,
        )
        self._ray_grids: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}
        self.reset()

    # ---- the navigator interface ---------------------------------------------------------------
    def reset(self) -> None:
        """Forget masks, the centreline, the corridor width, the EMA and the mode counts."""
        self._fusion.reset()
        self._centre: tuple[float, ...] | None = None
        self._width: float | None = None
        self._trunk_width: float | None = None
        self._smoother.rest()
        self.mode_counts = dict.fromkeys(MODES, 0)

    def statistics(self) -> dict[str, float]:
        """Shares of this run's commands found on one row, on the trunks and by the fallback
        (`methods.METHOD_STATISTICS`); none before the first command."""
        total = sum(self.mode_counts.values())
        if not total:
            return {}
        counts = self.mode_counts
        return {
            "one_side_share": counts["one_side"] / total,
            "trunk_share": counts["trunks"] / total,
            "fallback_share": counts["fallback"] / total,
        }

    def step(
        self,
        mask: np.ndarray,
        depth: np.ndarray,
        attitude: tuple[float, float] | None = None,
        rgb: np.ndarray | None = None,
        stamp: float = 0.0,
    ) -> CorridorCommand:
        """Take one mask + depth frame taken at `stamp` seconds (and the IMU's (roll, pitch) and
        the image, if any) and return the smoothed command."""
        mask_b, depth_m = _validated_frame(mask, depth)
        self.push_mask(mask_b, stamp)
        fused = self._fusion.fused()
        assert fused is not None
        return self._command(fused, depth_m, validated_attitude(attitude), validated_rgb(rgb, depth_m.shape))

    def push_mask(self, mask: np.ndarray, stamp: float = 0.0) -> None:
        """Add one mask to the fusion window (the paper's OR of the last `fuse_frames`); `stamp`
        (its frame time, s) lets `fused_mask(not_before=...)` leave it out once stale."""
        self._fusion.push(validated_mask(mask), stamp)

    def fused_mask(self, not_before: float | None = None) -> np.ndarray | None:
        """The OR of the window's masks (stale ones left out with `not_before`), None if none."""
        return self._fusion.fused(not_before)

    def command(
        self,
        fused: np.ndarray,
        depth: np.ndarray,
        attitude: tuple[float, float] | None = None,
        rgb: np.ndarray | None = None,
    ) -> CorridorCommand:
        """The smoothed command for an already fused mask, the newest depth frame, the IMU's
        (roll, pitch) in radians (None: level ground assumed) and the newest image (None: the
        trunk test trusts the mask alone)."""
        mask_b, depth_m = _validated_frame(fused, depth)
        return self._command(mask_b, depth_m, validated_attitude(attitude), validated_rgb(rgb, depth_m.shape))

    def stop(self) -> Command:
        """An invalid stop; the EMA restarts from rest and the centreline is forgotten."""
        self._smoother.rest()
        self._centre = None
        return CorridorCommand(v=0.0, omega=0.0, target_column=None, histogram=np.zeros(0), valid=False)

    # ---- one command -----------------------------------------------------------------------------
    def _command(
        self,
        fused: np.ndarray,
        depth_m: np.ndarray,
        attitude: tuple[float, float] | None,
        rgb: np.ndarray | None = None,
    ) -> CorridorCommand:
        config = self.config
        if fused.shape != (self.camera.height, self.camera.width):
            raise ValueError(
                f"mask is {fused.shape[1]}x{fused.shape[0]} but the camera geometry is "
                f"{self.camera.width}x{self.camera.height}"
            )
        centre, mode = self._centreline(fused, depth_m, attitude, rgb)
        histogram = np.zeros(0)
        if centre is None:
            self._centre = None
            histogram = smoothed_histogram(
                fused,
                depth_m,
                method="segmind",
                depth_threshold=config.depth_threshold,
                smooth_window=self._fallback.smooth_window,
            )
            column = histogram_minimum(histogram)
            v, omega = control_law(column, fused.shape[1], self._fallback)
        else:
            if self._centre is not None:  # the row moves little between commands: average out noise
                memory = config.centre_memory
                centre = tuple((1 - memory) * old + memory * new for old, new in zip(self._centre, centre))
            self._centre = centre
            # centre_hold's short lookahead needs the heading damping that only a row fit measures: in
            # trunk mode (the centreline along the robot) it weaved out of the high trees' rows
            holding = config.controller == "centre_hold" and mode in OBSERVED_MODES
            lookahead = config.hold_lookahead if holding else config.lookahead
            y_goal = float(polyval(lookahead, centre))
            v, omega = self._pursuit(y_goal, lookahead)
            if holding:
                omega = self._centre_hold_law(centre, omega, attitude)
            column = self.camera.column_of(lookahead, y_goal)
        self.mode_counts[mode] += 1
        v, omega = self._smoother.update(v, omega)
        return CorridorCommand(
            v=v,
            omega=omega,
            target_column=float(column),
            histogram=histogram,
            valid=True,
            mode=mode,
            centre=centre,
        )

    def _centreline(
        self, fused: np.ndarray, depth_m: np.ndarray, attitude: tuple[float, float] | None, rgb: np.ndarray | None
    ) -> tuple[tuple[float, ...] | None, str]:
        """Coefficients of the centreline and the mode that found it (None, "fallback" without one)."""
        config = self.config
        x, y, h = self._row_points(fused, depth_m, attitude)
        overhead = int(np.count_nonzero(h >= config.roof_min_height))
        if overhead >= config.min_points and overhead >= config.roof_share * h.shape[0]:
            # Most vegetation in range is overhead: the rows are not walls. Under a roof with an
            # opening along the corridor (a pergola's free band) SegMinD's column follows the
            # opening; under a closed canopy (merged crowns) the trunks give the rows.
            if self._roof_opening(y[h >= config.roof_min_height]) >= config.roof_opening:
                return None, "fallback"
            return self._trunk_centreline(fused, depth_m, attitude, rgb, self._split_line(fused, depth_m))
        offset = y - polyval(x, self._split_line(fused, depth_m))
        # Points further than the corridor width w from the centreline belong to the next rows (at
        # 1.5 w): in tight rows and through gaps they would pull the fit. Before w is known, the
        # nearest walls give it (`_first_reach`).
        low = h <= config.h_max
        reach = self._first_reach(offset[low]) if self._width is None else min(config.max_lateral, self._width)
        near = (np.abs(offset) <= reach) & low
        rows = {"left": near & (offset > 0), "right": near & (offset <= 0)}
        points = {name: (x[chosen], y[chosen]) for name, chosen in rows.items()}
        seen = [name for name in rows if self._enough(points[name][0])]
        if len(seen) == 2 and self._width is not None and config.row_start_max < math.inf:
            seen = self._rows_starting_near(seen, points)
        fit = None
        while seen:
            fit = fit_parallel_rows(
                [points[name] for name in seen],
                trim=config.trim,
                iterations=config.trim_iterations,
                degree=config.degree,
                significance=config.significance,
            )
            if fit is None or min(fit.kept) >= config.min_points:
                break
            seen.pop(int(np.argmin(fit.kept)))  # a row the trimming thinned out is not seen
            fit = None
        if fit is None:
            return None, "fallback"
        if len(seen) == 2 and fit.offsets[0] > fit.offsets[1]:
            width = fit.offsets[0] - fit.offsets[1]
            memory = config.width_memory
            self._width = width if self._width is None else (1 - memory) * self._width + memory * width
            return ((fit.offsets[0] + fit.offsets[1]) / 2.0, *fit.shape), "both"
        if self._width is None:
            return None, "fallback"
        k = int(np.argmax(fit.kept))  # the row with more support (the only one, if one)
        shift = -self._width / 2.0 if seen[k] == "left" else self._width / 2.0
        return (fit.offsets[k] + shift, *fit.shape), "one_side"

    def _first_reach(self, offset: np.ndarray) -> float:
        """How far from the split line the rows' points may lie before the corridor width is known:
        1.5 x the free width between the nearest walls (the 10th percentile of each side's distance).

        The next row on a side stands a whole row spacing (free width + canopy) beyond the bordering
        one, so with the robot in the corridor its near face is at least 1.5 free widths away, while
        the bordering row's far side is nearer as long as its canopy is thinner than the free width.
        Without this, rows seen through gaps (30 % missing vines) set the first width at 2.6 m
        instead of 1.3, and the fits drifted across the corridor (docs/nav_eval.md)."""
        limit = self.config.max_lateral
        left, right = offset[(offset > 0) & (offset <= limit)], -offset[(offset <= 0) & (offset >= -limit)]
        if min(left.shape[0], right.shape[0]) < self.config.min_points:
            return limit
        return min(limit, 1.5 * float(np.quantile(left, 0.1) + np.quantile(right, 0.1)))

    def _rows_starting_near(self, seen: list[str], points: dict[str, tuple[np.ndarray, np.ndarray]]) -> list[str]:
        """The two seen rows, less the one that starts beyond `row_start_max` (the 10th percentile of
        its points' x) when the other starts nearer: then the corridor is the near row's, moved by
        half the running width (one_side).

        Through a run of missing trees one row is seen only 4-7 m ahead while the other is seen from
        1 m. The parallel fit's shared slope is then the near row's, and the far row's line,
        extrapolated back over 4 m of a bend, put the centre 0.3-0.5 m to the side for seconds
        (slope_pear_2); the near row alone places the goal at 1 m well."""
        far = [name for name in seen if float(np.quantile(points[name][0], 0.1)) > self.config.row_start_max]
        return [name for name in seen if name not in far] if len(far) == 1 else seen

    def _roof_opening(self, lateral: np.ndarray) -> float:
        """Width (m) of the widest band along the robot, within `roof_opening_reach` of it (`lateral`:
        the roof points' y), that holds (almost) no roof point: 0.75-1.25 m under the test pergola, 0-0.25 m
        under the merged crowns of the high trees (docs/nav_eval.md)."""
        reach = self.config.roof_opening_reach
        counts = np.histogram(lateral, bins=round(2 * reach / ROOF_BIN), range=(-reach, reach))[0]
        widest = run = 0
        for empty in counts < 2:
            run = run + 1 if empty else 0
            widest = max(widest, run)
        return widest * ROOF_BIN

    def _split_line(self, fused: np.ndarray, depth_m: np.ndarray) -> tuple[float, ...]:
        """The line that splits left from right: the previous centreline, or the ray through
        SegMinD's column."""
        if self._centre is not None:
            return self._centre
        column = self._split_column(fused, depth_m)
        return (0.0, (self.camera.cx - column) / self.camera.fx / math.cos(math.radians(self.camera.tilt_deg)))

    def _trunk_centreline(
        self,
        fused: np.ndarray,
        depth_m: np.ndarray,
        attitude: tuple[float, float] | None,
        rgb: np.ndarray | None,
        split: tuple[float, ...],
    ) -> tuple[tuple[float, ...] | None, str]:
        """Under a roof: the centreline between the trunks (and posts) of the two rows, from the
        non-vegetation pixels standing `trunk_h_min`-`trunk_h_max` above the ground."""
        config = self.config
        pixel_index, rays = self._strided_rays(fused.shape, config.trunk_stride)
        chosen = np.flatnonzero(~fused[:: config.trunk_stride, :: config.trunk_stride])
        if rgb is not None:  # bark and posts are not green; leaves the mask missed are
            rows, cols = np.divmod(pixel_index[chosen], fused.shape[1])
            colour = rgb[rows, cols].astype(np.float32)
            excess_green = 2.0 * colour[:, 1] - colour[:, 0] - colour[:, 2]
            chosen = chosen[excess_green <= config.trunk_max_excess_green]
        z = depth_m.ravel()[pixel_index[chosen]]
        valid = np.flatnonzero(z > 0)
        ray_columns = np.take(rays, chosen[valid], axis=1)
        # The height band is measured from the ground the robot stands on (its own frame, not
        # levelled): across a slope the level plane through the robot cuts the uphill row's ground
        # and passes under the downhill row's crowns. The positions are levelled (trunks stand
        # along gravity).
        x, y, h = self.camera.points_on_rays(ray_columns, z[valid])
        if attitude is not None:
            x, y, _ = self.camera.level(x, y, h, attitude)
        ok = (x >= config.x_min) & (x <= config.trunk_x_max) & (h >= config.trunk_h_min) & (h <= config.trunk_h_max)
        x, y = x[ok], y[ok]
        offset = y - polyval(x, split)
        # Once the trunk-to-trunk width w is known, the next rows' trunks (at 1.5 w) are left out.
        reach = (
            config.trunk_max_lateral if self._trunk_width is None else min(config.trunk_max_lateral, self._trunk_width)
        )
        near = np.abs(offset) <= reach
        # A trunk or two a side give no reliable heading: the centreline is taken along the robot
        # (the goal is then the middle between the trunks ahead, which also turns out a heading error).
        shape = (0.0,) * config.degree  # as many coefficients as the row fits give: the centreline
        # is averaged with the next one coefficient by coefficient
        sides, counts = {}, {}
        for name, chosen_side in (("left", near & (offset > 0)), ("right", near & (offset <= 0))):
            counts[name] = int(np.count_nonzero(chosen_side))
            if counts[name] >= config.trunk_min_points:
                sides[name] = float(np.median(y[chosen_side]))
        if len(sides) == 2 and sides["left"] > sides["right"]:
            width = sides["left"] - sides["right"]
            memory = config.width_memory
            self._trunk_width = (
                width if self._trunk_width is None else (1 - memory) * self._trunk_width + memory * width
            )
            return ((sides["left"] + sides["right"]) / 2.0, *shape), "trunks"
        if len(sides) >= 1 and self._trunk_width is not None:
            name, row = max(sides.items(), key=lambda side: counts[side[0]])  # the side with more support
            return (row + (-self._trunk_width / 2.0 if name == "left" else self._trunk_width / 2.0), *shape), "trunks"
        return None, "fallback"

    def _split_column(self, fused: np.ndarray, depth_m: np.ndarray) -> float:
        """SegMinD's target column, found on every `stride`-th pixel in both directions: the split
        line only needs the direction of the free corridor, and the strided grid finds it for a
        fraction of the full histogram's cost (the fallback's command still uses the full one)."""
        s = self.config.stride
        window = max(1, self._fallback.smooth_window // s) | 1  # odd, about the same width in pixels
        column = target_column(
            fused[::s, ::s],
            depth_m[::s, ::s],
            method="segmind",
            depth_threshold=self.config.depth_threshold,
            smooth_window=window,
        )
        assert column is not None  # only SegZeros finds no target
        return s * column

    def _enough(self, x: np.ndarray) -> bool:
        """Whether a row's points can support a fit: `min_points` of them spanning `min_span` in x."""
        return x.shape[0] >= self.config.min_points and float(x.max() - x.min()) >= self.config.min_span

    def _row_points(
        self, fused: np.ndarray, depth_m: np.ndarray, attitude: tuple[float, float] | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Robot-frame (x, y, h) of the kept vegetation pixels (every `stride`-th, in range, above
        `h_min`; those above `h_max` only count for the roof test)."""
        config = self.config
        pixel_index, rays = self._strided_rays(fused.shape, config.stride)
        chosen = np.flatnonzero(fused[:: config.stride, :: config.stride])
        z = depth_m.ravel()[pixel_index[chosen]]
        x, y, h = self.camera.points_on_rays(np.take(rays, chosen, axis=1), z, attitude)
        # NaN and infinite depth fail the range tests (NaN compares false, inf lands out of range).
        ok = np.flatnonzero((z > 0) & (x >= config.x_min) & (x <= config.x_max) & (h >= config.h_min))
        if ok.shape[0] > config.max_points:  # an even thinning bounds the step time on dense walls
            ok = ok[:: -(-ok.shape[0] // config.max_points)]
        return x[ok], y[ok], h[ok]

    def _strided_rays(self, shape: tuple[int, int], s: int) -> tuple[np.ndarray, np.ndarray]:
        """For every `s`-th pixel in both directions, in row-major order: its flat index in the full
        image and the camera's ray coefficients (a 3 x n array, cached per image shape and stride).
        A step then looks up only the vegetation pixels instead of masking whole images."""
        if (*shape, s) not in self._ray_grids:
            rows, cols = np.meshgrid(np.arange(0, shape[0], s), np.arange(0, shape[1], s), indexing="ij")
            rays = self.camera.ray_coefficients(rows.ravel().astype(np.float32), cols.ravel().astype(np.float32))
            self._ray_grids[(*shape, s)] = ((rows * shape[1] + cols).ravel(), np.stack(rays).astype(np.float32))
        return self._ray_grids[(*shape, s)]

    def _centre_hold_law(self, centre: tuple[float, ...], omega: float, attitude: tuple[float, float] | None) -> float:
        """Pure pursuit's yaw rate `omega` (on the short lookahead) plus heading damping and the
        slope feedforward (step 6), on a fitted centreline (modes "both", "one_side").

        The goal's offset c(L) is the best-measured number of the fit (the points lie around it);
        c_0 alone, the offset at the robot, is an extrapolation whose error is the heading's times
        3-4 m, so the law steers on c(L) and adds a small heading term. Across a slope the robot
        creeps downhill at a drift angle k_s tan(roll); the law alone balances that only with a
        standing offset 1.6 k_s tan(roll) m downhill, so `hold_slope_drift` k_s points the robot
        uphill by that angle from the IMU's roll (`_slope_feedforward`) (docs/reference/equations.md)."""
        config = self.config
        omega += config.hold_heading_gain * math.atan(centre[1]) + self._slope_feedforward(attitude)
        return clip(omega, -config.omega_max, config.omega_max)

    def _slope_feedforward(self, attitude: tuple[float, float] | None) -> float:
        """centre_hold's yaw rate that points the robot uphill against its creep down a cross slope
        (0 without `hold_slope_drift` or without the IMU).

        A skid-steer robot whose wheels roll across a slope slides downhill at about
        d = -k_s tan(roll) v (roll > 0: left side up, creep to the right). To hold the centre it must
        point by -d / v = k_s tan(roll) against it; the law's heading gain, (2 v / L_h + k_h), would
        turn that heading out again, so the feedforward is that gain times the angle. Unlike an
        integral it reads no fit, so it adds none of the fit's bias, and it follows the roll at
        once where the ground's roughness changes it from metre to metre."""
        config = self.config
        if config.hold_slope_drift == 0.0 or attitude is None:
            return 0.0
        heading_gain = 2.0 * config.v_max / config.hold_lookahead + config.hold_heading_gain
        return heading_gain * config.hold_slope_drift * math.tan(attitude[0])

    def _pursuit(self, y_goal: float, lookahead: float) -> tuple[float, float]:
        """Unsmoothed (v, omega) of pure pursuit to the goal (lookahead, y_goal)."""
        config = self.config
        kappa = 2.0 * y_goal / (lookahead * lookahead + y_goal * y_goal)
        alpha = math.atan2(y_goal, lookahead)
        alpha_max = math.atan2(self.camera.width / 2.0, self.camera.fx)
        v = config.v_max * max(0.0, 1.0 - (alpha / alpha_max) ** 2)
        # The nominal speed, not the slowed one: a robot that slows for a large bearing still turns.
        omega = clip(config.v_max * kappa, -config.omega_max, config.omega_max)
        return v, omega


if TYPE_CHECKING:  # both navigators are what the runtime drives (checked by mypy)
    _NAVIGATORS: tuple[type[MaskNavigator], ...] = (Navigator, CorridorNavigator)
