"""Drivable-strip labels of a photo set: the ground between the rows that the robot may drive on.

A set carries them in a `strips/` folder beside its photos, one file per photo named by the
photo's stem: `strips/<stem>.png` (a mask, non-zero = drivable, the photo's size) or
`strips/<stem>.json` (`{"polygon": [[x, y], ...]}` in pixel coordinates of the photo, at least
three points, every point inside the image). Photos without one are scored without the strip
figures; a strip file whose photo is not in the set, a mask of another size or a point outside
the image is refused with one line naming the file, since a label that does not fit its photo
would give a silently wrong figure.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from segmin.data.agriseg_loader import DatasetError, Frame, read_mask

STRIPS_FOLDER = "strips"
STRIP_SUFFIXES = (".png", ".json")


def find_strips(data_root: str | Path, frames: list[Frame]) -> dict[Path, Path]:
    """Each photo's strip file (by image path), for the photos that have one; {} without a strips folder.
    Photos are matched by stem, so with a strips folder two photos of one stem are refused."""
    folder = Path(data_root) / STRIPS_FOLDER
    if not folder.is_dir():
        return {}
    photos: dict[str, Path] = {}
    for frame in frames:  # a strip is named by its photo's stem: two photos of one stem are ambiguous
        other = photos.setdefault(frame.image_path.stem, frame.image_path)
        if other != frame.image_path:
            raise DatasetError(
                f"{folder}: photos {other} and {frame.image_path} share the stem {frame.image_path.stem!r}; "
                "strip labels need photos named apart"
            )
    strips: dict[Path, Path] = {}
    for path in sorted(folder.iterdir()):
        if path.name.startswith(".") or not path.is_file():
            continue
        if path.suffix.lower() not in STRIP_SUFFIXES:
            raise DatasetError(f"{path}: not a strip label (expected {' or '.join(STRIP_SUFFIXES)})")
        photo = photos.get(path.stem)
        if photo is None:
            raise DatasetError(f"{path}: no photo named {path.stem!r} in the set")
        if photo in strips:
            raise DatasetError(f"{path}: a second strip label for {photo.name} (also {strips[photo].name})")
        strips[photo] = path
    return strips


def read_strip(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """The strip as a bool mask of the photo's `shape` (height, width); DatasetError naming the file."""
    height, width = shape
    if path.suffix.lower() == ".png":
        mask = read_mask(path) > 0
        if mask.shape != (height, width):
            raise DatasetError(
                f"{path}: strip mask size {mask.shape[1]}x{mask.shape[0]} does not match its photo's {width}x{height}"
            )
    else:
        mask = _polygon_mask(path, height, width)
    if not mask.any():
        raise DatasetError(f"{path}: empty drivable strip")
    return mask


def _polygon_mask(path: Path, height: int, width: int) -> np.ndarray:
    try:
        polygon = np.asarray(json.loads(path.read_text(encoding="utf-8"))["polygon"], dtype=np.float64)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DatasetError(f'{path}: expected {{"polygon": [[x, y], ...]}} ({type(exc).__name__}: {exc})') from None
    if polygon.ndim != 2 or polygon.shape[1] != 2 or polygon.shape[0] < 3 or not np.isfinite(polygon).all():
        raise DatasetError(f"{path}: polygon must be at least three finite [x, y] points")
    outside = (polygon[:, 0] < 0) | (polygon[:, 0] > width) | (polygon[:, 1] < 0) | (polygon[:, 1] > height)
    if outside.any():
        x, y = polygon[np.argmax(outside)]
        raise DatasetError(f"{path}: strip point ({x:g}, {y:g}) lies outside the {width}x{height} image")
    mask = np.zeros((height, width), np.uint8)
    cv2.fillPoly(mask, [np.round(polygon).astype(np.int32)], 1)
    return mask.astype(bool)
