"""The SegCorridor navigator: the masks and depth of a frame, through the rows' points and their
fit (or the trunks, or SegMinD's fallback), to a smoothed command."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..camera import CameraGeometry
from ..control import Command, CommandSmoother
from ..mask_fusion import MaskFusion, validated_mask
from ..navigator import (
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
from ..protocols import MaskNavigator, NavigatorInputs
from .config import (
    MAX_LATERAL,
    MIN_SPAN,
    ROOF_MIN_HEIGHT,
    ROOF_OPENING_REACH,
    ROOF_SHARE,
    SIGNIFICANCE,
    TRIM_ITERATIONS,
    WIDTH_MEMORY,
    CorridorConfig,
)
from .rays import StridedRays
from .row_fit import fit_parallel_rows, polyval
from .steering import centre_hold, pursuit
from .trunk_mode import TrunkFinder, roof_opening

MODES = ("both", "one_side", "trunks", "fallback")
OBSERVED_MODES = ("both", "one_side")  # the modes whose centreline has a measured heading


@dataclass(frozen=True)
class CorridorCommand(Command):
    """A command plus how it was found: `mode` is one of MODES; `centre` the coefficients
    (c_0, c_1[, c_2]) of the centreline y = c_0 + c_1 x (+ c_2 x^2) in the robot frame (None in
    fallback). `histogram` is SegMinD's smoothed histogram in fallback, else empty."""

    mode: str = "fallback"
    centre: tuple[float, ...] | None = None


class CorridorNavigator:
    """The stateful SegCorridor navigator (the package's docstring), a `MaskNavigator`."""

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
        self._rays = StridedRays(camera)
        self._trunks = TrunkFinder(config, camera, self._rays)
        self.reset()

    # ---- the navigator interface ---------------------------------------------------------------
    def reset(self) -> None:
        """Forget masks, the centreline, the corridor width, the EMA and the mode counts."""
        self._fusion.reset()
        self._centre: tuple[float, ...] | None = None
        self._width: float | None = None
        self._trunks.reset()
        self._smoother.rest()
        self.mode_counts = dict.fromkeys(MODES, 0)

    @property
    def corridor_width(self) -> float | None:
        """The running corridor width (m) between the fitted rows, None before two rows were seen:
        read by the live view to draw the rows beside the centreline."""
        return self._width

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
            v, omega = pursuit(y_goal, lookahead, config, self.camera)
            if holding:
                omega = centre_hold(centre, omega, attitude, config)
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
        overhead = int(np.count_nonzero(h >= ROOF_MIN_HEIGHT))
        if overhead >= config.min_points and overhead >= ROOF_SHARE * h.shape[0]:
            # Most vegetation in range is overhead: the rows are not walls. Under a roof with an
            # opening along the corridor (a pergola's free band) SegMinD's column follows the
            # opening; under a closed canopy (merged crowns) the trunks give the rows.
            if roof_opening(y[h >= ROOF_MIN_HEIGHT], ROOF_OPENING_REACH) >= config.roof_opening:
                return None, "fallback"
            return self._trunks.centreline(fused, depth_m, attitude, rgb, self._split_line(fused, depth_m))
        offset = y - polyval(x, self._split_line(fused, depth_m))
        # Points further than the corridor width w from the centreline belong to the next rows (at
        # 1.5 w): in tight rows and through gaps they would pull the fit. Before w is known, the
        # nearest walls give it (`_first_reach`).
        low = h <= config.h_max
        reach = self._first_reach(offset[low]) if self._width is None else min(MAX_LATERAL, self._width)
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
                iterations=TRIM_ITERATIONS,
                degree=config.degree,
                significance=SIGNIFICANCE,
            )
            if fit is None or min(fit.kept) >= config.min_points:
                break
            seen.pop(int(np.argmin(fit.kept)))  # a row the trimming thinned out is not seen
            fit = None
        if fit is None:
            return None, "fallback"
        if len(seen) == 2 and fit.offsets[0] > fit.offsets[1]:
            width = fit.offsets[0] - fit.offsets[1]
            memory = WIDTH_MEMORY
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
        limit = MAX_LATERAL
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

    def _split_line(self, fused: np.ndarray, depth_m: np.ndarray) -> tuple[float, ...]:
        """The line that splits left from right: the previous centreline, or the ray through
        SegMinD's column."""
        if self._centre is not None:
            return self._centre
        column = self._split_column(fused, depth_m)
        return (0.0, (self.camera.cx - column) / self.camera.fx / math.cos(math.radians(self.camera.tilt_deg)))

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
        return x.shape[0] >= self.config.min_points and float(x.max() - x.min()) >= MIN_SPAN

    def _row_points(
        self, fused: np.ndarray, depth_m: np.ndarray, attitude: tuple[float, float] | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Robot-frame (x, y, h) of the kept vegetation pixels (every `stride`-th, in range, above
        `h_min`; those above `h_max` only count for the roof test)."""
        config = self.config
        pixel_index, rays = self._rays.grid(fused.shape, config.stride)
        chosen = np.flatnonzero(fused[:: config.stride, :: config.stride])
        z = depth_m.ravel()[pixel_index[chosen]]
        x, y, h = self.camera.points_on_rays(np.take(rays, chosen, axis=1), z, attitude)
        # NaN and infinite depth fail the range tests (NaN compares false, inf lands out of range).
        ok = np.flatnonzero((z > 0) & (x >= config.x_min) & (x <= config.x_max) & (h >= config.h_min))
        if ok.shape[0] > config.max_points:  # an even thinning bounds the step time on dense walls
            ok = ok[:: -(-ok.shape[0] // config.max_points)]
        return x[ok], y[ok], h[ok]


if TYPE_CHECKING:  # both navigators are what the runtime drives (checked by mypy)
    _NAVIGATORS: tuple[type[MaskNavigator], ...] = (Navigator, CorridorNavigator)
