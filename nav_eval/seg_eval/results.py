"""eval-seg's result files: results.csv (per image), results.json (summary, definitions, per image), contact_sheet.png.

All written atomically, and never over earlier results unless forced: a second run into the same
folder is refused before any model runs.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.atomic import write_bytes, write_json, write_text
from segmin.common.outputs import check_results_absent
from segmin.nav_eval.seg_eval.summary import EvalSummary

RESULT_FILES: tuple[str, ...] = ("results.csv", "results.json", "contact_sheet.png")


def check_out_dir(out: str | Path, force: bool) -> Path:
    """Refuse to overwrite earlier results unless forced (called before any work is done)."""
    return check_results_absent(out, RESULT_FILES, force, "eval-seg")


def write_results(
    summary: EvalSummary, sheet: np.ndarray | None, out: str | Path, *, force: bool = False
) -> dict[str, str]:
    """results.csv (per image), results.json (summary, definitions, per image), contact_sheet.png; atomic."""
    out = check_out_dir(out, force)
    rows = [r.row() for r in summary.images]
    buffer = io.StringIO()
    columns = list(rows[0]) if rows else ["name"]
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: _csv_value(v) for k, v in row.items()})
    paths = {"csv": out / "results.csv", "json": out / "results.json"}
    write_text(paths["csv"], buffer.getvalue())
    write_json(paths["json"], summary.as_dict())
    if sheet is not None:
        paths["contact_sheet"] = out / "contact_sheet.png"
        write_png(paths["contact_sheet"], sheet)
    return {k: str(v) for k, v in paths.items()}


def _csv_value(value: Any) -> Any:
    """Figures to six significant digits; an undefined one reads "n/a", as the command prints it."""
    if isinstance(value, float):
        return "n/a" if math.isnan(value) else f"{value:.6g}"
    return value


def write_png(path: Path, rgb: np.ndarray) -> None:
    """An RGB uint8 image as a PNG, written atomically (OpenCV encodes BGR)."""
    import cv2

    ok, png = cv2.imencode(".png", np.ascontiguousarray(rgb[:, :, ::-1]))
    if not ok:
        raise RuntimeError(f"{path}: PNG encoding failed")
    write_bytes(path, png.tobytes())
