"""eval-seg's contact sheet: where a model fails, one captioned row per photo under a legend.

Each row is photo | prediction vs ground truth | ground truth: crop found green, false crop
(predicted, not labelled) red, missed crop (labelled, not predicted) blue.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from segmin.common.figures import format_figure
from segmin.data.overlay import tint_mask
from segmin.nav_eval.seg_eval.summary import EvalSummary, ImageResult

# Contact-sheet colours (RGB): right crop, false crop, missed crop.
TRUE_CROP = (0, 200, 0)
FALSE_CROP = (230, 0, 0)
MISSED_CROP = (0, 90, 255)
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
    row = np.concatenate([np.concatenate([p, np.full((height, 2, 3), 255, np.uint8)], axis=1) for p in panels], axis=1)[
        :, :-2
    ]
    caption = np.full((20, row.shape[1], 3), 40, np.uint8)
    c = result.counts
    _label(
        caption,
        f"{result.name}   IoU {format_figure(c.iou)}   precision {format_figure(c.precision)}   recall {format_figure(c.recall)}",
        (4, 14),
        0.42,
    )
    return np.concatenate([caption, row], axis=0)


def contact_sheet(rows: list[np.ndarray], summary: EvalSummary) -> np.ndarray:
    """Rows stacked under a header: title, column names and the colour legend."""
    import cv2

    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 2), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    header = np.full((78, width, 3), 40, np.uint8)
    f = summary.figures()
    title = (
        f"{Path(summary.model).name} on {Path(summary.data).name}: {f['images']} images, mean IoU "
        f"{format_figure(f['mean_iou'])}, pooled IoU {format_figure(f['pooled_iou'])}, P {format_figure(f['precision'])}, R {format_figure(f['recall'])}"
    )
    _label(header, title, (6, 18), 0.45)
    panel = width // 3
    for k, name in enumerate(("photo", "prediction vs ground truth", "ground truth")):
        _label(header, name, (k * panel + 6, 42), 0.45)
    x = 6
    for colour, text in (
        (TRUE_CROP, "crop, found"),
        (FALSE_CROP, "false crop (predicted, not labelled)"),
        (MISSED_CROP, "missed crop (labelled, not predicted)"),
    ):
        cv2.rectangle(header, (x, 56), (x + 14, 70), tuple(int(v) for v in colour), -1)
        _label(header, text, (x + 20, 69), 0.42)
        x += 30 + 8 * len(text)
    return np.concatenate([header, *rows], axis=0)
