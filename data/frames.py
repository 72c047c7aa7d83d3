"""A labelled frame, the result of a scan, and the pairing rule: by frame id, never by position.

The reference code pairs images and masks by sorted position, which silently mispairs as soon as
one folder is missing; here an image and a mask pair only when their frame ids are equal, and
anything left over is recorded as unpaired (see `layouts.scan`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
DEPTH_EXTS = (".png", ".exr", ".tif", ".tiff")

_TRAILING_INT = re.compile(r"(\d+)(?!.*\d)")


class DatasetError(ValueError):
    """Bad dataset input; the message names the file or folder and the problem."""


@dataclass(frozen=True)
class Frame:
    """One labelled frame: where its image, mask and (optional) depth live."""

    domain: str
    subset: str
    frame_id: int
    image_path: Path
    mask_path: Path
    depth_path: Path | None = None

    @property
    def key(self) -> tuple[str, str, int]:
        """The identity used in split files: (domain, subset, frame_id)."""
        return (self.domain, self.subset, self.frame_id)


@dataclass
class ScanResult:
    """Everything `scan` found: paired frames, problems (strings naming files) and layouts."""

    frames: list[Frame] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    unpaired: list[str] = field(default_factory=list)
    layouts: dict[str, str] = field(default_factory=dict)  # subset folder -> layout name


def frame_id_of(name: str) -> int | None:
    """The integer N of `ImageN` / `Image0010.png` / `frame_12`, or None when there is none."""
    stem = Path(name).stem if Path(name).suffix.lower() in IMAGE_EXTS + DEPTH_EXTS else name
    match = _TRAILING_INT.search(stem)
    return int(match.group(1)) if match else None


def pair_frames(
    domain: str,
    subset: str,
    folder: Path,
    img: dict[int, Path],
    msk: dict[int, Path],
    dep: dict[int, Path],
    result: ScanResult,
) -> None:
    """Add a Frame to `result` for every id that has both an image and a mask; record the rest."""
    for n in sorted(set(img) | set(msk)):
        if n not in img:
            result.unpaired.append(f"{msk[n]}: mask of frame {n} has no image")
        elif n not in msk:
            result.unpaired.append(f"{img[n]}: image of frame {n} has no mask")
        else:
            result.frames.append(Frame(domain, subset, n, img[n], msk[n], dep.get(n)))
    if not img and not msk:
        result.problems.append(f"{folder}: empty (no image or mask files)")
