"""The metrics core (segmin.common.seg_metrics): exact figures of hand-counted masks, empty-mask conventions,
and the two summaries of a set (pooled vs mean over images) that must not be confused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from segmin.common.seg_metrics import ConfusionMatrix, PixelCounts, confusion


def rows(*crop_rows: int, shape: tuple[int, int] = (8, 8)) -> np.ndarray:
    """An 8 x 8 mask whose listed rows are crop (8 pixels each)."""
    mask = np.zeros(shape, bool)
    mask[list(crop_rows)] = True
    return mask


def test_counts_and_figures_of_hand_made_masks() -> None:
    # truth rows 0-3 (32 px), prediction rows 2-4 (24 px): rows 2-3 right (16 TP), row 4 false
    # (8 FP), rows 0-1 missed (16 FN), rows 5-7 empty in both (24 TN).
    counts = confusion(rows(2, 3, 4), rows(0, 1, 2, 3))
    assert counts == PixelCounts(tp=16, fp=8, fn=16, tn=24)
    assert counts.pixels == 64
    assert counts.iou == 0.4  # 16 / (16 + 8 + 16) = 16 / 40
    assert counts.precision == 2 / 3  # 16 / (16 + 8)
    assert counts.recall == 0.5  # 16 / (16 + 16): precision and recall are not swapped
    assert counts.pixel_accuracy == 0.625  # (16 + 24) / 64
    assert list(counts.metrics()) == ["iou", "precision", "recall", "pixel_accuracy"]  # eval-seg's column order
    perfect = confusion(rows(0, 1), rows(0, 1))
    assert perfect.metrics() == {"iou": 1.0, "precision": 1.0, "recall": 1.0, "pixel_accuracy": 1.0}


def test_empty_mask_conventions() -> None:
    nothing = np.zeros((8, 8), bool)
    # Empty truth, empty prediction: nothing to find, nothing claimed -> IoU 1.0, precision and recall undefined.
    empty = confusion(nothing, nothing)
    assert empty == PixelCounts(tn=64)
    assert empty.iou == 1.0 and empty.pixel_accuracy == 1.0
    assert math.isnan(empty.precision) and math.isnan(empty.recall)
    # Crop missed entirely: IoU 0, recall 0, precision undefined (nothing predicted).
    missed = confusion(nothing, rows(0))
    assert (missed.iou, missed.recall, missed.pixel_accuracy) == (0.0, 0.0, 0.875)  # 56 / 64 right
    assert math.isnan(missed.precision)
    # Crop claimed where there is none: IoU 0, precision 0, recall undefined (nothing to find).
    claimed = confusion(rows(0), nothing)
    assert (claimed.iou, claimed.precision) == (0.0, 0.0)
    assert math.isnan(claimed.recall)
    # No pixels at all: pixel accuracy is undefined, not 1.
    assert math.isnan(PixelCounts().pixel_accuracy) and PixelCounts().iou == 1.0


def test_confusion_treats_any_non_zero_as_crop_and_refuses_shape_mismatches() -> None:
    truth = rows(0).astype(np.uint8) * 255
    assert confusion(rows(0).astype(np.float32), truth) == PixelCounts(tp=8, tn=56)
    with pytest.raises(ValueError, match=r"prediction shape \(3, 8\) differs from the ground truth \(8, 8\)"):
        confusion(rows(0)[:3], truth)


def test_counts_add_up_and_come_back_from_reduced_float_sums() -> None:
    assert PixelCounts(1, 2, 3, 4) + PixelCounts(10, 20, 30, 40) == PixelCounts(11, 22, 33, 44)
    # training reduces float64 sums over DDP ranks in (tp, fp, fn, tn) order
    assert PixelCounts.from_values([16.0, 8.0, 16.0, 24.0]) == PixelCounts(tp=16, fp=8, fn=16, tn=24)


def three_images() -> ConfusionMatrix:
    """Images whose mean over images and pooled figures differ (counted by hand in each line)."""
    return ConfusionMatrix(
        (
            confusion(rows(0, 1), rows(0)),  # a: TP 8, FP 8, FN 0, TN 48 -> IoU 0.5, P 0.5, R 1.0
            confusion(rows(0), rows(0, 1, 2, 3)),  # b: TP 8, FP 0, FN 24, TN 32 -> IoU 0.25, P 1.0, R 0.25
            confusion(rows(), rows()),  # c: TN 64 only -> IoU 1.0, P and R undefined
        )
    )


def test_mean_over_images_is_not_the_pooled_figure() -> None:
    matrix = three_images()
    # Pooled: TP 16, FP 8, FN 24, TN 144 (the empty image adds only TN).
    assert matrix.pooled == PixelCounts(tp=16, fp=8, fn=24, tn=144)
    assert matrix.pooled.iou == 1 / 3  # 16 / (16 + 8 + 24) = 16 / 48
    assert matrix.pooled.precision == 2 / 3  # 16 / 24
    assert matrix.pooled.recall == 0.4  # 16 / 40
    assert matrix.pooled.pixel_accuracy == 5 / 6  # (16 + 144) / 192
    # Mean over images: every image weighs the same, the empty one with its IoU of 1.0.
    assert matrix.mean_iou == 7 / 12  # (0.5 + 0.25 + 1.0) / 3 = 1.75 / 3
    assert matrix.mean("iou") == matrix.mean_iou
    # (0.875 + 0.625 + 1.0) / 3: equal to the pooled figure only because the images have the same size
    assert matrix.mean("pixel_accuracy") == 5 / 6


def test_means_leave_out_images_where_a_figure_is_undefined() -> None:
    matrix = three_images()
    assert matrix.mean("precision") == 0.75  # (0.5 + 1.0) / 2: image c predicts nothing
    assert matrix.mean("recall") == 0.625  # (1.0 + 0.25) / 2: image c has nothing to find
    assert matrix.undefined("precision") == 1 and matrix.undefined("recall") == 1 and matrix.undefined("iou") == 0
    nothing_predicted = ConfusionMatrix((confusion(rows(), rows(0)),))
    assert math.isnan(nothing_predicted.mean("precision")) and math.isnan(nothing_predicted.pooled.precision)


def test_an_empty_set() -> None:
    matrix = ConfusionMatrix(())
    assert math.isnan(matrix.mean_iou) and matrix.pooled == PixelCounts() and matrix.undefined("iou") == 0
