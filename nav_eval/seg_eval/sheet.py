"""eval-seg's contact sheet: where a model fails, one captioned row per photo under a legend.

Each row is photo | prediction vs ground truth | ground truth: crop found green, false crop
(predicted, not labelled) red, missed crop (labelled, not predicted) blue. The middle panel also
shows where each mask would steer (`steering`): the truth's target as a white line over a yellow
band marking its free corridor at the bottom, the model's target as a magenta line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from segmin.common.figures import format_figure
from segmin.data.overlay import tint_mask
from segmin.nav_eval.seg_eval.steering import STEERING_WIDTH, PhotoSteering
from segmin.nav_eval.seg_eval.summary import EvalSummary, ImageResult

# Contact-sheet colours (RGB): right crop, false crop, missed crop.
TRUE_CROP = (0, 200, 0)
FALSE_CROP = (230, 0, 0)
MISSED_CROP = (0, 90, 255)
# Steering marks (RGB): the truth's target and corridor, the model's target.
TRUTH_TARGET = (255, 255, 255)
CORRIDOR = (255, 220, 0)
MODEL_TARGET = (255, 0, 255)
SHEET_ROW_HEIGHT = 200
SHEET_MAX_ROWS = 24


def sheet_picks(count: int, rows: int) -> set[int]:
    """Indices of up to `rows` evenly spaced images out of `count` (none when either is 0)."""
    if rows <= 0 or count <= 0:
        return set()
    return set(np.linspace(0, count - 1, min(rows, count)).round().astype(int).tolist())


def error_overlay(rgb: np.ndarray, prediction: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """True crop green, false crop (predicted, not labelled) red, missed crop (labelled, not predicted) blue."""
    out = tint_mask(rgb, prediction & truth, TRUE_CROP, 0.45)
    out = tint_mask(out, prediction & ~truth, FALSE_CROP, 0.55)
    return tint_mask(out, ~prediction & truth, MISSED_CROP, 0.55)


def _label(image: np.ndarray, text: str, origin: tuple[int, int], scale: float = 0.45) -> None:
    """White text on the sheet's dark strips (captions never sit on the photo, so they stay legible)."""
    import cv2

    cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA)


def sheet_row(
    image: np.ndarray, prediction: np.ndarray, truth: np.ndarray, result: ImageResult, height: int = SHEET_ROW_HEIGHT
) -> np.ndarray:
    """photo | prediction with errors coloured | ground truth (tinted green), captioned with its figures."""
    import cv2

    panels = [image, error_overlay(image, prediction, truth), tint_mask(image, truth, TRUE_CROP, 0.5)]
    width = max(1, round(image.shape[1] * height / image.shape[0]))
    panels = [cv2.resize(p, (width, height), interpolation=cv2.INTER_AREA) for p in panels]
    if result.steering is not None:
        draw_steering(panels[1], result.steering)
    row = np.concatenate([np.concatenate([p, np.full((height, 2, 3), 255, np.uint8)], axis=1) for p in panels], axis=1)[
        :, :-2
    ]
    caption = np.full((20, row.shape[1], 3), 40, np.uint8)
    c = result.counts
    text = f"{result.name}   IoU {format_figure(c.iou)}   precision {format_figure(c.precision)}   recall {format_figure(c.recall)}"
    if result.steering is not None:
        where = "in corridor" if result.steering.in_corridor else "OUTSIDE corridor"
        text += f"   target error {result.steering.error_px:.1f} px, {where}"
    _label(caption, text, (4, 14), 0.42)
    return np.concatenate([caption, row], axis=0)


def draw_steering(panel: np.ndarray, steering: PhotoSteering) -> None:
    """The truth's corridor (band at the bottom) and target (white) and the model's target (magenta), in place."""
    import cv2

    height, width = panel.shape[:2]

    def x(column: float) -> int:  # the panel pixel under a column's centre
        return min(width - 1, int((column + 0.5) * width / STEERING_WIDTH))

    band = max(3, height // 30)
    start, stop = steering.corridor
    left, right = int(start * width / STEERING_WIDTH), min(width, int((stop + 1) * width / STEERING_WIDTH)) - 1
    cv2.rectangle(panel, (left, height - band), (right, height - 1), CORRIDOR, -1)
    cv2.line(panel, (x(steering.truth_target), 0), (x(steering.truth_target), height - 1), TRUTH_TARGET, 2)
    cv2.line(panel, (x(steering.model_target), 0), (x(steering.model_target), height - 1), MODEL_TARGET, 2)


def contact_sheet(rows: list[np.ndarray], summary: EvalSummary) -> np.ndarray:
    """Rows stacked under a header: title, column names and the colour legend."""
    import cv2

    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 2), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    header = np.full((100, width, 3), 40, np.uint8)
    f = summary.figures()
    title = (
        f"{Path(summary.model).name} on {Path(summary.data).name}: {f['images']} images, mean IoU "
        f"{format_figure(f['mean_iou'])}, pooled IoU {format_figure(f['pooled_iou'])}, P {format_figure(f['precision'])}, R {format_figure(f['recall'])}"
    )
    _label(header, title, (6, 18), 0.45)
    panel = width // 3
    for k, name in enumerate(("photo", "prediction vs ground truth", "ground truth")):
        _label(header, name, (k * panel + 6, 42), 0.45)
    legend = (
        (
            (TRUE_CROP, "crop, found"),
            (FALSE_CROP, "false crop (predicted, not labelled)"),
            (MISSED_CROP, "missed crop (labelled, not predicted)"),
        ),
        (
            (TRUTH_TARGET, "truth's steering target"),
            (CORRIDOR, "truth's free corridor"),
            (MODEL_TARGET, "model's steering target"),
        ),
    )
    for line, entries in enumerate(legend):
        x, top = 6, 56 + 22 * line
        for colour, text in entries:
            cv2.rectangle(header, (x, top), (x + 14, top + 14), tuple(int(v) for v in colour), -1)
            _label(header, text, (x + 20, top + 13), 0.42)
            x += 30 + 8 * len(text)
    return np.concatenate([header, *rows], axis=0)
