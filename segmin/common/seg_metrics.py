"""Crop-segmentation metrics, all derived from one set of pixel counts (TP, FP, FN, TN).

Training's validation IoU, the export check's mask IoU, the resolution ceiling of
`python -m benchmarks iou-bound` and the figures of `segmin eval-seg` are computed here, so that an
"IoU" means the same thing wherever segmin prints one. As in torchvision's reference
`ConfusionMatrix`, callers only count pixels and every figure is derived from the counts.
Numpy only: the export check runs on the robot's bare install. Training counts on its own
device with torch (`train.metrics`) and hands the summed counts to `PixelCounts.from_values`.

Definitions (the same in all four places):
- IoU = TP / (TP + FP + FN); 1.0 when the truth and the prediction are both empty (nothing to
  find, nothing claimed: a perfect answer, not an undefined one).
- precision = TP / (TP + FP); NaN (undefined) when nothing is predicted.
- recall = TP / (TP + FN); NaN when the truth is empty.
- pixel accuracy = (TP + TN) / pixels; NaN when there are no pixels.

A set of images is summarised in two ways that genuinely differ, both kept by name:
- pooled (`ConfusionMatrix.pooled`): the formulas on counts summed over the set. Training,
  export verification and the IoU bound report only this; a large image weighs more, and the
  pooled precision stays defined as long as anything anywhere is predicted.
- mean over images (`ConfusionMatrix.mean`): each image's figure, averaged; every image weighs
  the same (eval-seg's "mean IoU over images"). Images where a figure is undefined are left out
  of its mean.

Turning probabilities into masks is the caller's job, and the callers differ on purpose:
training and the IoU bound predict crop where p > threshold (logit > 0), export verification
and eval-seg where p >= threshold, as the robot's `OnnxSegmenter` does.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

import numpy as np

Metric = Literal["iou", "precision", "recall", "pixel_accuracy"]


@dataclass(frozen=True)
class PixelCounts:
    """Confusion counts of the crop class (one image or a whole set); every metric is derived from these."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0

    @classmethod
    def from_values(cls, values: Iterable[float]) -> PixelCounts:
        """Counts from four numbers in (tp, fp, fn, tn) order, e.g. float64 sums reduced over DDP ranks."""
        tp, fp, fn, tn = (int(value) for value in values)
        return cls(tp, fp, fn, tn)

    def __add__(self, other: PixelCounts) -> PixelCounts:
        return PixelCounts(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn, self.tn + other.tn)

    @property
    def pixels(self) -> int:
        return self.tp + self.fp + self.fn + self.tn

    @property
    def iou(self) -> float:
        union = self.tp + self.fp + self.fn
        return self.tp / union if union else 1.0  # empty truth, empty prediction: perfect

    @property
    def precision(self) -> float:
        predicted = self.tp + self.fp
        return self.tp / predicted if predicted else math.nan  # nothing predicted: undefined

    @property
    def recall(self) -> float:
        actual = self.tp + self.fn
        return self.tp / actual if actual else math.nan  # nothing to find: undefined

    @property
    def pixel_accuracy(self) -> float:
        return (self.tp + self.tn) / self.pixels if self.pixels else math.nan

    def metrics(self) -> dict[str, float]:
        """Every figure of these counts, in the order eval-seg writes its columns."""
        return {
            "iou": self.iou,
            "precision": self.precision,
            "recall": self.recall,
            "pixel_accuracy": self.pixel_accuracy,
        }


def confusion(prediction: np.ndarray, truth: np.ndarray) -> PixelCounts:
    """Counts of two same-shape masks (anything non-zero is crop); a shape mismatch is an error."""
    if prediction.shape != truth.shape:
        raise ValueError(f"prediction shape {prediction.shape} differs from the ground truth {truth.shape}")
    pred, gt = np.asarray(prediction, bool), np.asarray(truth, bool)
    tp = int(np.count_nonzero(pred & gt))
    fp = int(np.count_nonzero(pred & ~gt))
    fn = int(np.count_nonzero(~pred & gt))
    return PixelCounts(tp, fp, fn, int(pred.size) - tp - fp - fn)


@dataclass(frozen=True)
class ConfusionMatrix:
    """The counts of every image of a set, kept apart so both summaries derive from them."""

    images: tuple[PixelCounts, ...]

    @property
    def pooled(self) -> PixelCounts:
        """The set's counts summed: the pooled figures are this object's metrics."""
        total = PixelCounts()
        for counts in self.images:
            total = total + counts
        return total

    def mean(self, metric: Metric) -> float:
        """Mean of `metric` over the images where it is defined; NaN when it is defined on none."""
        values = [value for value in (getattr(counts, metric) for counts in self.images) if not math.isnan(value)]
        return float(np.mean(values)) if values else math.nan

    def undefined(self, metric: Metric) -> int:
        """How many images `metric` is undefined on (left out of `mean`)."""
        return sum(math.isnan(getattr(counts, metric)) for counts in self.images)

    @property
    def mean_iou(self) -> float:
        """Mean over images of the per-image IoU (defined on every image), not the pooled IoU."""
        return self.mean("iou")
