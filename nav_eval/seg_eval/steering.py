"""Where a model's mask would steer the robot, against where the true mask would: eval-seg's steering figures.

IoU counts pixels everywhere in the photo, but the navigator only reads one thing from a mask:
the column with the least vegetation. A model can gain IoU on the canopy at the sides and still
paint a hedge across the vanishing point, which moves that column to the image edge. These
figures score what the robot steers by.

Per photo (definitions also in docs/reference/metrics.md):

1. Both masks are brought to `STEERING_WIDTH` (224) px of width, the width the paper's node and
   the shipped models steer at, keeping the aspect ratio (the mask as 0/1 floats resampled, area
   average when shrinking, bilinear when enlarging, then a majority vote: >= 0.5), so an error in
   px means the same on any photo.
2. Each goes through the navigator's own SegMin rule without depth (the paper's rule on the
   mask alone: `column_histogram`, the moving average of `smooth_window` columns, the global
   minimum with ties averaged), giving the model's target x_m and the truth's target x_t.
3. The target error is |x_m - x_t| in px at 224.
4. The truth's free corridor: the columns whose smoothed truth histogram h stays within
   `CORRIDOR_FRACTION` of its range above the minimum (h <= min + 0.25 (max - min)), kept as the
   runs of such columns that hold a truth minimum. It is the gap the truth would steer into,
   as wide as it is clearly free; `in_corridor` says whether x_m falls inside it or within
   `AGREEMENT_PX` of x_t (when the truth's minima lie apart, the paper's tie rule averages them
   and x_t itself may fall between the gaps; agreeing with the truth is never an error). A flat
   truth histogram (no crop, or crop in every column alike) has no preferred column: every
   column is in the corridor.
5. `at_edge`: x_m within `EDGE_FRACTION` of the width from either border (a target pushed to
   the image edge, what a row end painted as crop does).

A photo set may carry a drivable-strip label (the ground the robot may drive on, `strips`):
then `in_strip` says whether the strip reaches column x_m (in any row), and `crop_on_strip`
is the share of strip pixels the model paints as crop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from segmin.nav_eval.runtime.navigator import NavigatorConfig, histogram_minimum, smoothed_histogram

STEERING_WIDTH = 224
SMOOTH_WINDOW = NavigatorConfig.smooth_window  # the paper's moving average, the navigator's default
CORRIDOR_FRACTION = 0.25
EDGE_FRACTION = 0.05
AGREEMENT_PX = 1.0


@dataclass(frozen=True)
class SteeringTarget:
    """One mask's SegMin target at `STEERING_WIDTH`, its smoothed histogram and (for a truth) its corridor."""

    column: float
    histogram: np.ndarray

    def corridor(self) -> np.ndarray:
        """bool per column: the truth's free corridor (module docstring, item 4)."""
        h = self.histogram
        low, high = float(h.min()), float(h.max())
        if high - low <= 1e-9 * (1.0 + high):
            return np.ones(h.shape[0], bool)
        free = h <= low + CORRIDOR_FRACTION * (high - low)
        minima = h <= low + 1e-9 * (1.0 + float(np.abs(h).sum()))
        edges = np.flatnonzero(np.diff(np.concatenate(([0], free.astype(np.int8), [0]))))
        corridor = np.zeros_like(free)
        for start, stop in edges.reshape(-1, 2):
            if minima[start:stop].any():
                corridor[start:stop] = True
        return corridor


@dataclass(frozen=True)
class PhotoSteering:
    """The steering figures of one photo (px at `STEERING_WIDTH`)."""

    model_target: float
    truth_target: float
    error_px: float
    in_corridor: bool
    at_edge: bool
    corridor: tuple[int, int]  # first and last corridor column around the truth target (for the sheet)
    in_strip: bool | None = None  # None: the set has no drivable-strip label
    crop_on_strip: float | None = None

    def row(self) -> dict[str, Any]:
        """The per-photo columns of results.csv / results.json."""
        return {
            "target_model_px": round(self.model_target, 3),
            "target_truth_px": round(self.truth_target, 3),
            "target_error_px": round(self.error_px, 3),
            "target_in_corridor": self.in_corridor,
            "target_at_edge": self.at_edge,
            "corridor_px": f"{self.corridor[0]}-{self.corridor[1]}",
            **({} if self.in_strip is None else {"target_in_strip": self.in_strip}),
            **({} if self.crop_on_strip is None else {"crop_on_strip": round(self.crop_on_strip, 6)}),
        }


def to_steering_width(mask: np.ndarray) -> np.ndarray:
    """A bool H x W mask at `STEERING_WIDTH` columns, aspect kept (area average, majority vote)."""
    height, width = mask.shape
    if width == STEERING_WIDTH:
        return mask.astype(bool)
    scaled_height = max(1, round(height * STEERING_WIDTH / width))
    shrink = cv2.INTER_AREA if width > STEERING_WIDTH else cv2.INTER_LINEAR
    scaled = cv2.resize(mask.astype(np.float32), (STEERING_WIDTH, scaled_height), interpolation=shrink)
    return scaled >= 0.5


def segmin_target(mask: np.ndarray) -> SteeringTarget:
    """The paper's SegMin target of a mask without depth (every vegetation pixel counts as near)."""
    small = to_steering_width(mask)
    everywhere = np.ones(small.shape, np.float32)  # depth 1 m under a 2 m threshold: every pixel counts
    histogram = smoothed_histogram(small, everywhere, method="segmin", depth_threshold=2.0, smooth_window=SMOOTH_WINDOW)
    return SteeringTarget(histogram_minimum(histogram), histogram)


def photo_steering(prediction: np.ndarray, truth: np.ndarray, strip: np.ndarray | None = None) -> PhotoSteering:
    """Model vs truth target of one photo; `strip` (bool, the photo's size) adds the strip figures."""
    model = segmin_target(prediction)
    reference = segmin_target(truth)
    corridor = reference.corridor()
    column = int(round(model.column))
    around = _run_around(corridor, int(round(reference.column)))
    edge = EDGE_FRACTION * STEERING_WIDTH
    error = abs(model.column - reference.column)
    in_strip = crop_on_strip = None
    if strip is not None:
        in_strip = bool(strip_columns(strip)[column])
        crop_on_strip = float(prediction[strip].mean())  # never empty: strips.read_strip refuses that
    return PhotoSteering(
        model_target=model.column,
        truth_target=reference.column,
        error_px=error,
        in_corridor=bool(corridor[column]) or error <= AGREEMENT_PX,
        at_edge=bool(model.column < edge or model.column > STEERING_WIDTH - 1 - edge),
        corridor=around,
        in_strip=in_strip,
        crop_on_strip=crop_on_strip,
    )


def strip_columns(strip: np.ndarray) -> np.ndarray:
    """bool per column at `STEERING_WIDTH`: the strip reaches it in some row (a column it only grazes counts)."""
    reached = np.asarray(strip.any(axis=0), np.float32)[None]
    return np.asarray(cv2.resize(reached, (STEERING_WIDTH, 1), interpolation=cv2.INTER_AREA))[0] > 0


def _run_around(corridor: np.ndarray, column: int) -> tuple[int, int]:
    """The corridor run that holds `column` (or the nearest corridor column's run)."""
    inside = np.flatnonzero(corridor)
    anchor = int(inside[np.argmin(np.abs(inside - column))])
    start = anchor
    while start > 0 and corridor[start - 1]:
        start -= 1
    stop = anchor
    while stop < corridor.shape[0] - 1 and corridor[stop + 1]:
        stop += 1
    return start, stop


def steering_figures(photos: list[PhotoSteering]) -> dict[str, Any]:
    """The set's summary: error median / mean / worst, and the counts outside the corridor and at the edge."""
    if not photos:
        return {}
    errors = np.array([p.error_px for p in photos])
    figures: dict[str, Any] = {
        "target_error_median_px": float(np.median(errors)),
        "target_error_mean_px": float(errors.mean()),
        "target_error_worst_px": float(errors.max()),
        "targets_outside_corridor": sum(not p.in_corridor for p in photos),
        "targets_at_edge": sum(p.at_edge for p in photos),
    }
    strips = [p for p in photos if p.in_strip is not None]
    if strips:
        figures["strip_photos"] = len(strips)
        figures["targets_outside_strip"] = sum(not p.in_strip for p in strips)
        shares = [p.crop_on_strip for p in strips if p.crop_on_strip is not None and not math.isnan(p.crop_on_strip)]
        figures["crop_on_strip_mean"] = float(np.mean(shares)) if shares else math.nan
    return figures


STEERING_DEFINITIONS = {
    "steering": (
        f"SegMin without depth (the paper's rule on the mask alone) on each mask brought to {STEERING_WIDTH} px of "
        f"width: column histogram, moving average of {SMOOTH_WINDOW} columns, global minimum (ties averaged)"
    ),
    "target_error_px": f"|model target - truth target| in px at {STEERING_WIDTH} px of width",
    "target_in_corridor": (
        f"model target inside the truth's free corridor: the runs of columns holding a truth minimum where the "
        f"smoothed truth histogram is <= min + {CORRIDOR_FRACTION} (max - min), or within {AGREEMENT_PX:g} px of the "
        "truth's target; every column when the histogram is flat"
    ),
    "target_at_edge": f"model target within {EDGE_FRACTION:.0%} of the width from either image border",
    "target_in_strip": "the drivable-strip label reaches the model target's column (in any row)",
    "crop_on_strip": "share of the drivable strip's pixels the model paints as crop",
}
