"""What `segmin eval-seg` found: per-image counts, the set's figures, and how they read.

Every figure derives from the pixel counts of `segmin.common.seg_metrics` (definitions there):
per image, pooled over the set (`pooled_iou`, `precision`, `recall`, `pixel_accuracy`), and
`mean_iou`, the mean of the per-image IoUs (every photo weighs the same). The pooled figures
stay defined whenever any pixel is predicted (precision) or labelled (recall), however many
single images are undefined; undefined figures print "n/a" and are null in JSON. Beside
them, the steering figures (`steering`: the target the navigator would take from the model's
mask against the truth's) and the share of uniform frames the model paints (`blank_frames`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from segmin.common.figures import format_figure
from segmin.common.seg_metrics import ConfusionMatrix, PixelCounts
from segmin.nav_eval.seg_eval.blank_frames import BLANK_FRAME_LIMIT
from segmin.nav_eval.seg_eval.steering import STEERING_DEFINITIONS, PhotoSteering, steering_figures


@dataclass
class ImageResult:
    """One photo's counts and where it came from."""

    name: str
    image: str
    mask: str
    width: int
    height: int
    counts: PixelCounts
    steering: PhotoSteering | None = None

    def row(self) -> dict[str, Any]:
        c = self.counts
        return {
            "name": self.name,
            "image": self.image,
            "mask": self.mask,
            "width": self.width,
            "height": self.height,
            "gt_pixels": c.tp + c.fn,
            "pred_pixels": c.tp + c.fp,
            "tp": c.tp,
            "fp": c.fp,
            "fn": c.fn,
            "tn": c.tn,
            **c.metrics(),
            **(self.steering.row() if self.steering is not None else {}),
        }


@dataclass
class EvalSummary:
    """The whole set: per-image results and the summary figures."""

    model: str
    data: str
    kind: str  # "onnx" or "checkpoint"
    threshold: float
    input_size: tuple[int, int]
    truth_closing: int = 0  # px; > 0: scored against the canopy region, not the exact masks
    images: list[ImageResult] = field(default_factory=list)
    blank_frames: dict[str, float] = field(default_factory=dict)  # uniform frame -> share painted as crop

    @property
    def matrix(self) -> ConfusionMatrix:
        """The per-image counts, from which both the pooled figures and the means over images derive."""
        return ConfusionMatrix(tuple(result.counts for result in self.images))

    def figures(self) -> dict[str, Any]:
        """The summary numbers (pooled precision/recall stay defined when single images are not)."""
        matrix = self.matrix
        pooled = matrix.pooled
        return {
            "images": len(self.images),
            "mean_iou": matrix.mean_iou,
            "pooled_iou": pooled.iou,
            "precision": pooled.precision,
            "recall": pooled.recall,
            "pixel_accuracy": pooled.pixel_accuracy,
            "mean_precision": matrix.mean("precision"),
            "mean_recall": matrix.mean("recall"),
            "images_without_prediction": matrix.undefined("precision"),
            "images_without_crop": matrix.undefined("recall"),
            **steering_figures([r.steering for r in self.images if r.steering is not None]),
            **({"blank_frames_worst": max(self.blank_frames.values())} if self.blank_frames else {}),
        }

    def as_dict(self) -> dict[str, Any]:
        return {
            "format": "segmin-seg-eval-v1",
            "model": self.model,
            "data": self.data,
            "kind": self.kind,
            "threshold": self.threshold,
            "input_size": list(self.input_size),
            "truth_closing": self.truth_closing,
            "summary": json_safe(self.figures()),
            "blank_frames": self.blank_frames,
            "definitions": {**DEFINITIONS, **STEERING_DEFINITIONS},
            "rows": [json_safe(r.row()) for r in self.images],
        }

    def summary_lines(self) -> list[str]:
        """What the command prints: one line per figure."""
        f = self.figures()
        h, w = self.input_size
        lines = [
            f"{self.model} ({self.kind}, input {h}x{w}, threshold {self.threshold:g}) on {self.data}: "
            f"{f['images']} images"
            + (f", truth closed with a {self.truth_closing} px disc (canopy region)" if self.truth_closing else ""),
            f"  mean IoU over images  {format_figure(f['mean_iou'])}",
            f"  pooled IoU            {format_figure(f['pooled_iou'])}",
            f"  precision (pooled)    {format_figure(f['precision'])}",
            f"  recall (pooled)       {format_figure(f['recall'])}",
            f"  pixel accuracy        {format_figure(f['pixel_accuracy'])}",
        ]
        if "target_error_median_px" in f:
            lines.append(
                f"  steering target error median {f['target_error_median_px']:.1f} px, mean "
                f"{f['target_error_mean_px']:.1f}, worst {f['target_error_worst_px']:.1f} (at 224 px of width)"
            )
            lines.append(
                f"  targets outside the free corridor {f['targets_outside_corridor']} of {f['images']}, "
                f"at the image edge {f['targets_at_edge']}"
            )
        if "strip_photos" in f:
            lines.append(
                f"  targets outside the drivable strip {f['targets_outside_strip']} of {f['strip_photos']}, "
                f"crop painted on the strip {format_figure(f['crop_on_strip_mean'])} (mean share)"
            )
        if self.blank_frames:
            worst = max(self.blank_frames, key=self.blank_frames.__getitem__)
            verdict = (
                "ok" if self.blank_frames[worst] < BLANK_FRAME_LIMIT else f"over the {BLANK_FRAME_LIMIT:.0%} limit"
            )
            lines.append(f"  uniform frames painted as crop: worst {self.blank_frames[worst]:.2%} ({worst}), {verdict}")
        if f["images_without_prediction"]:
            lines.append(f"  {f['images_without_prediction']} image(s) with no crop predicted: precision n/a there")
        if f["images_without_crop"]:
            lines.append(f"  {f['images_without_crop']} image(s) with no crop in the ground truth: recall n/a there")
        return lines


DEFINITIONS = {
    "iou": "TP / (TP + FP + FN); 1.0 when the ground truth and the prediction are both empty",
    "precision": "TP / (TP + FP); null (n/a) when nothing is predicted",
    "recall": "TP / (TP + FN); null (n/a) when the ground truth is empty",
    "pixel_accuracy": "(TP + TN) / pixels",
    "mean_iou": "mean of the per-image IoUs",
    "pooled": "pooled_iou, precision, recall, pixel_accuracy: the same formulas on counts summed over all images",
    "truth_closing": "radius in px of the disc the ground truth was closed with before scoring (0: exact masks)",
    "resolution": "prediction resized (bilinear probability) to the ground-truth mask size, then thresholded",
    "blank_frames": "share of each uniform frame (black, white, grey, colours) at the model's input size painted as crop",
}


def json_safe(values: dict[str, Any]) -> dict[str, Any]:
    """NaN is not JSON: undefined figures become null (results.json, the pipeline's stage record)."""
    return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in values.items()}
