"""SegMin, SegMinD and SegZeros: from a vegetation mask and a depth frame to (v, omega).

This follows the paper's equations (Navone et al., section 2), not the reference code's quirks:

1. fuse the last N masks with a logical OR (with `mask_closing`, beyond the paper, each mask is
   first closed with a disc: a model's small holes inside a crown then do not read as free
   columns);
2. keep a mask pixel only where its depth is valid and <= d_th (0, NaN, inf and negative depth
   are "no reading", never "near vegetation");
3. SegMin sums the kept pixels per column; SegMinD weights each kept pixel by 1 - depth/d_th
   (near vegetation weighs more) and sums in floating point;
4. a moving average of `smooth_window` columns whose window shrinks at the image borders (no
   zero padding, which would make the border look free);
5. the target column x_h is the global minimum, the mean of all minimum columns on ties;
6. d = x_h - c, v = v_max (1 - d^2 / (w/2)^2), omega = -omega_gain d, clipped, then smoothed with
   an EMA y_t = (1 - lambda) y_{t-1} + lambda u_t.

c is the image centre in 0-based column coordinates, (w - 1) / 2: a symmetric scene then gives
d = 0 exactly (the paper's w/2 is the same centre in pixel-edge coordinates).

SegZeros (Aghi et al. 2021, the baseline) takes the centre of the widest run of vegetation-free
columns in the raw column sums and has a parabolic law in both terms. Without such a run it has
no target and the navigator commands a stop. The stateful `Navigator` adds that method's
temporal rules: at start-up it ignores runs reaching into the outer image borders, then it
tracks the run nearest its previous target.

Everything here is numpy, vectorised, with no I/O and no globals: arrays in, a command out,
state only in the `Navigator` instance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from segmin.common.mask_closing import check_closing_radius

from .checks import check_depth_threshold, check_positive
from .control import Command, CommandSmoother, clip, stop_command
from .mask_fusion import MaskFusion, validated_mask
from .methods import DEPTH_METHODS, PAPER_METHODS
from .protocols import NavigatorInputs

# SegZeros: a free corridor must be wider than 3 columns (Aghi et al. 2021).
ZEROS_MIN_WIDTH = 4


@dataclass(frozen=True)
class NavigatorConfig:
    """Every parameter of the navigator; defaults are the paper's (section 3.1).

    `depth_threshold` has no default on purpose: the paper uses 5 m in vineyards, 8 m in pear
    rows and pergolas and 10 m under tall trees, and a silent default would be wrong for most.
    """

    method: str
    depth_threshold: float
    fuse_frames: int = 3
    # Beyond the paper (0: off): each mask closed with a disc of this radius before the fusion, in
    # px at 224 px of image width (nav_eval.runtime.mask_closing: the same on any camera). The
    # shipped trees model paints the branches and holes inside a crown unevenly; under tall trees
    # that tips SegMinD's near tie between the row ahead and the nearest trunk. 8 is the setting
    # to run that model with (docs/guide/models.md).
    mask_closing: int = 0
    smooth_window: int = 11
    v_max: float = 0.5
    omega_max: float = 1.0
    omega_gain: float = 0.01
    ema_lambda: float = 0.5
    zeros_min_width: int = ZEROS_MIN_WIDTH
    zeros_startup_border: float = 0.2
    zeros_track_tolerance: float = 0.02

    def __post_init__(self) -> None:
        _check_method(self.method)
        check_depth_threshold(self.depth_threshold)
        _check_window(self.smooth_window)
        if isinstance(self.fuse_frames, bool) or not isinstance(self.fuse_frames, int) or self.fuse_frames < 1:
            raise ValueError(f"fuse_frames must be an integer >= 1, got {self.fuse_frames!r}")
        check_closing_radius(self.mask_closing, "mask_closing")
        for name in ("v_max", "omega_max"):
            check_positive(name, getattr(self, name))
        if not (math.isfinite(self.omega_gain) and self.omega_gain >= 0):
            raise ValueError(f"omega_gain must be a finite number >= 0, got {self.omega_gain!r}")
        if not (0.0 < self.ema_lambda <= 1.0):
            raise ValueError(f"ema_lambda must be in (0, 1], got {self.ema_lambda!r}")
        if (
            isinstance(self.zeros_min_width, bool)
            or not isinstance(self.zeros_min_width, int)
            or self.zeros_min_width < 1
        ):
            raise ValueError(f"zeros_min_width must be an integer >= 1, got {self.zeros_min_width!r}")
        if not (0.0 <= self.zeros_startup_border < 0.5):
            raise ValueError(f"zeros_startup_border must be in [0, 0.5), got {self.zeros_startup_border!r}")
        if not (math.isfinite(self.zeros_track_tolerance) and self.zeros_track_tolerance >= 0):
            raise ValueError(f"zeros_track_tolerance must be a finite number >= 0, got {self.zeros_track_tolerance!r}")


# ---------------------------------------------------------------------------------------------
# Frame-level functions (stateless)
# ---------------------------------------------------------------------------------------------


def target_column(
    mask: np.ndarray,
    depth: np.ndarray,
    *,
    method: str,
    depth_threshold: float,
    smooth_window: int = 11,
) -> float | None:
    """The column x_h (0-based, fractional on ties) that `method` steers to, or None.

    `mask` is one (already fused) vegetation mask; `depth` the matching depth frame. None means
    no valid target, which only SegZeros returns (no run of free columns).
    """
    _check_method(method)
    check_depth_threshold(depth_threshold)
    _check_window(smooth_window)
    mask_b, depth_m = _validated_frame(mask, depth)
    if method == "segzeros":
        histogram = column_histogram(mask_b, depth_m, method=method, depth_threshold=depth_threshold)
        return widest_run_centre(free_runs(histogram, min_width=ZEROS_MIN_WIDTH), histogram.shape[0])
    return histogram_minimum(
        smoothed_histogram(mask_b, depth_m, method=method, depth_threshold=depth_threshold, smooth_window=smooth_window)
    )


def to_metres(depth: np.ndarray) -> np.ndarray:
    """Depth in metres as float32: uint16 is RealSense millimetres (0 = no reading)."""
    if depth.dtype == np.uint16:
        return depth.astype(np.float32) * np.float32(0.001)
    if np.issubdtype(depth.dtype, np.floating):
        return depth.astype(np.float32, copy=False)
    raise ValueError(f"depth must be float metres or uint16 millimetres, got dtype {depth.dtype}")


def column_histogram(mask: np.ndarray, depth_m: np.ndarray, *, method: str, depth_threshold: float) -> np.ndarray:
    """Per-column amount of near vegetation (float64, length w) before smoothing.

    A pixel counts when it is vegetation and its depth is valid and within the threshold.
    NaN compares false, and `depth > 0` drops 0 and negative readings, so invalid depth never
    counts. SegMinD weights each kept pixel by 1 - depth / d_th.
    """
    near = mask & (depth_m > 0) & (depth_m <= depth_threshold)
    counts = near.sum(axis=0, dtype=np.float64)
    if method == "segmind":
        # sum(1 - z/d_th) over kept pixels = count - sum(z)/d_th. `where`, not a product with the
        # mask: NaN or inf depth times False is NaN and would poison the whole column.
        kept_depth = np.where(near, depth_m, np.float32(0.0))
        return counts - kept_depth.sum(axis=0, dtype=np.float64) / depth_threshold
    return counts


def smoothed_histogram(
    mask: np.ndarray, depth_m: np.ndarray, *, method: str, depth_threshold: float, smooth_window: int
) -> np.ndarray:
    """The column histogram after the paper's moving average: what SegMin and SegMinD take the
    minimum of (the navigators, SegCorridor's fallback and the histogram figures share it)."""
    return moving_average(
        column_histogram(mask, depth_m, method=method, depth_threshold=depth_threshold), smooth_window
    )


def moving_average(histogram: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average of odd `window` that keeps the length.

    At the borders the window shrinks to the columns that exist, so the mean is over real
    columns only: zero padding would pull the border columns towards zero and make the image
    edge look like free space, which the minimum search would then pick.
    """
    w = histogram.shape[0]
    half = min(window // 2, w - 1) if w > 1 else 0
    cumulative = np.concatenate(([0.0], np.cumsum(histogram, dtype=np.float64)))
    columns = np.arange(w)
    lo = np.maximum(columns - half, 0)
    hi = np.minimum(columns + half + 1, w)
    return (cumulative[hi] - cumulative[lo]) / (hi - lo)


def histogram_minimum(histogram: np.ndarray) -> float:
    """Column of the global minimum; the mean of all columns that share it.

    Values within a rounding tolerance of the minimum count as equal, so ties produced by
    floating-point sums are still ties (and a mirrored frame gives the mirrored target).
    """
    low = histogram.min()
    tolerance = 1e-9 * (1.0 + float(np.abs(histogram).sum()))
    ties = np.flatnonzero(histogram <= low + tolerance)
    return float(ties.mean())


def free_runs(histogram: np.ndarray, *, min_width: int) -> np.ndarray:
    """Runs of consecutive vegetation-free columns as an (R, 2) array of [start, stop) indices."""
    free = np.concatenate(([False], histogram == 0, [False]))
    edges = np.flatnonzero(free[1:] != free[:-1])
    runs = edges.reshape(-1, 2)
    return runs[(runs[:, 1] - runs[:, 0]) >= min_width]


def widest_run_centre(runs: np.ndarray, width: int) -> float | None:
    """Centre column of the widest run, or None without runs.

    Equally wide runs are told apart by their distance to the image centre (the robot keeps
    the corridor it is facing); only a perfectly symmetric pair is left, and then the left one.
    """
    if len(runs) == 0:
        return None
    widths = runs[:, 1] - runs[:, 0]
    centres = (runs[:, 0] + runs[:, 1] - 1) / 2.0
    widest = widths == widths.max()
    offset = np.where(widest, np.abs(centres - (width - 1) / 2.0), np.inf)
    return float(centres[np.argmin(offset)])


def control_law(x_h: float, width: int, config: NavigatorConfig) -> tuple[float, float]:
    """Unsmoothed (v, omega) for a target column, clipped to the limits.

    SegMin/SegMinD: v = v_max (1 - d^2/(w/2)^2), omega = -omega_gain d. SegZeros keeps its own
    parabolic law: K = d^2/(w/2)^2, omega = -sign(d) omega_max K, v = v_max (1 - K).
    """
    d = x_h - (width - 1) / 2.0
    k = (d * d) / ((width / 2.0) ** 2)
    if config.method == "segzeros":
        v = config.v_max * (1.0 - k)
        omega = -math.copysign(config.omega_max * k, d) if d != 0 else 0.0
    else:
        v = config.v_max * (1.0 - k)
        omega = -config.omega_gain * d
    return clip(v, 0.0, config.v_max), clip(omega, -config.omega_max, config.omega_max)


# ---------------------------------------------------------------------------------------------
# The stateful navigator
# ---------------------------------------------------------------------------------------------


class Navigator:
    """Mask fusion over the last N masks, target search, control law and EMA smoothing.

    `step(mask, depth)` is the one-call form (push the mask, fuse, command). A caller that owns
    the timing, as `nav_eval.runtime.RowFollower` does (masks at the segmentation rate, commands
    at the command rate), uses the split of the runtime's `MaskNavigator` interface: `push_mask`
    per mask, `fused_mask` then `command` per command. Both forms run the same code, so they give
    the same commands.

    It reads depth (SegMinD needs it; SegMin and SegZeros run on the mask alone without it) and
    nothing else: the paper's methods steer on image columns. It keeps no per-run statistics.
    """

    def __init__(self, config: NavigatorConfig) -> None:
        self.config = config
        self.inputs = NavigatorInputs(depth=config.method in DEPTH_METHODS)
        self._smoother = CommandSmoother(config.ema_lambda)
        self._fusion = MaskFusion(config.fuse_frames, config.mask_closing)
        self.reset()

    def reset(self) -> None:
        """Forget past masks, the SegZeros track and the EMA (the robot is at rest)."""
        self._fusion.reset()
        self._smoother.rest()
        self._zeros_target: float | None = None

    def statistics(self) -> dict[str, float]:
        """None kept: the paper's methods have no modes to count."""
        return {}

    def step(self, mask: np.ndarray, depth: np.ndarray) -> Command:
        """Take one mask + depth frame and return the smoothed command."""
        mask_b, depth_m = _validated_frame(mask, depth)
        self._fusion.push(mask_b, 0.0)
        fused = self.fused_mask()
        assert fused is not None  # the mask just pushed is in the window
        return self._command(fused, depth_m)

    def push_mask(self, mask: np.ndarray, stamp: float = 0.0) -> None:
        """Add one mask to the fusion window (a ring of `fuse_frames`, no reallocation).

        `stamp` is the mask's frame time in seconds, used only by `fused_mask(not_before=...)`
        to leave out stale masks. A mask of another size than the window's starts a new window.
        """
        self._fusion.push(validated_mask(mask), stamp)

    def fused_mask(self, not_before: float | None = None) -> np.ndarray | None:
        """Logical OR of the masks in the window; with `not_before`, only those stamped at or
        after it (stale masks are left out). None when no mask qualifies."""
        return self._fusion.fused(not_before)

    def command(
        self,
        fused: np.ndarray,
        depth: np.ndarray,
        attitude: tuple[float, float] | None = None,
        rgb: np.ndarray | None = None,
    ) -> Command:
        """The smoothed command for an already fused mask and the newest depth frame (one EMA step).

        `attitude` (the IMU's roll, pitch) and `rgb` are the interface's: this navigator does not
        declare them in `inputs`, so the runtime gives None. A given attitude is still checked, so
        a caller's bad IMU reading is refused here as by SegCorridor; neither is used.
        """
        mask_b, depth_m = _validated_frame(fused, depth)
        validated_attitude(attitude)
        return self._command(mask_b, depth_m)

    def stop(self) -> Command:
        """An invalid stop command; the EMA restarts from rest (as after a lost target)."""
        self._smoother.rest()
        return stop_command()

    def _command(self, fused: np.ndarray, depth_m: np.ndarray) -> Command:
        config = self.config
        if config.method == "segzeros":
            histogram = column_histogram(fused, depth_m, method=config.method, depth_threshold=config.depth_threshold)
            target = self._track_free_run(histogram)
        else:
            histogram = smoothed_histogram(
                fused,
                depth_m,
                method=config.method,
                depth_threshold=config.depth_threshold,
                smooth_window=config.smooth_window,
            )
            target = histogram_minimum(histogram)
        width = histogram.shape[0]
        if target is None:
            self._smoother.rest()
            return stop_command(histogram)
        v, omega = self._smoother.update(*control_law(target, width, config))
        return Command(v=v, omega=omega, target_column=target, histogram=histogram, valid=True)

    def _track_free_run(self, histogram: np.ndarray) -> float | None:
        """SegZeros target with Aghi et al.'s start-up border rule and run tracking."""
        config = self.config
        width = histogram.shape[0]
        runs = free_runs(histogram, min_width=config.zeros_min_width)
        if self._zeros_target is None:
            border = config.zeros_startup_border * width
            inside = (runs[:, 0] >= border) & (runs[:, 1] <= width - border)
            target = widest_run_centre(runs[inside], width)
        else:
            target = self._nearest_run_centre(runs, self._zeros_target, config.zeros_track_tolerance * width)
        self._zeros_target = target
        return target

    @staticmethod
    def _nearest_run_centre(runs: np.ndarray, previous: float, tolerance: float) -> float | None:
        """Centre of the run nearest `previous`, if that run comes within `tolerance` columns."""
        if len(runs) == 0:
            return None
        gap = np.maximum(runs[:, 0] - previous, 0) + np.maximum(previous - (runs[:, 1] - 1), 0)
        best = int(np.argmin(gap))
        if gap[best] > tolerance:
            return None
        start, stop = runs[best]
        return (start + stop - 1) / 2.0


# ---------------------------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------------------------


def validated_rgb(rgb: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray | None:
    """The image as an H x W x 3 uint8 array of the depth frame's size, or None; ValueError otherwise
    (SegCorridor's trunk test reads its colour; the runtime checks it when the frame arrives)."""
    if rgb is None:
        return None
    image = np.asarray(rgb)
    if image.shape != (*shape, 3):
        raise ValueError(f"rgb must be {shape[1]}x{shape[0]}x3 like the depth frame, got shape {image.shape}")
    if image.dtype != np.uint8:  # the green test's threshold is on the 0-255 scale
        raise ValueError(f"rgb must be uint8 (0-255), got {image.dtype}")
    return image


def validated_attitude(attitude: object) -> tuple[float, float] | None:
    """None, or the IMU's (roll, pitch) as two finite floats within +-90 degrees (else ValueError)."""
    if attitude is None:
        return None
    try:
        values = tuple(float(v) for v in np.asarray(attitude, dtype=float).reshape(-1))
    except (TypeError, ValueError):
        values = ()
    if len(values) != 2 or not all(math.isfinite(v) and abs(v) < math.pi / 2 for v in values):
        raise ValueError(
            f"attitude must be (roll, pitch) in radians, two finite numbers within +-pi/2, got {attitude!r}"
        )
    return values[0], values[1]


def _validated_frame(mask: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Check shapes and dtypes; return a bool mask and float32 metres."""
    mask_b = validated_mask(mask)
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"depth must be a 2-D h x w array, got shape {depth.shape}")
    if mask_b.shape != depth.shape:
        raise ValueError(f"mask and depth must have the same shape, got mask {mask_b.shape} and depth {depth.shape}")
    return mask_b, to_metres(depth)


def _check_method(method: str) -> None:
    if method not in PAPER_METHODS:
        hint = " (segcorridor is nav_eval.corridor.CorridorNavigator)" if method == "segcorridor" else ""
        raise ValueError(f"method must be one of {list(PAPER_METHODS)}, got {method!r}{hint}")


def _check_window(value: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1 or value % 2 == 0:
        raise ValueError(f"smooth_window must be an odd integer >= 1, got {value!r}")
