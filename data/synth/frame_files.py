"""A dataset frame's files: where they go in the AgriSeg layout, their PNG encoding, and writing
them so that no reader sees part of a frame (layout: `segmin.data.synth.writer`).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from segmin.common.atomic import write_bytes
from segmin.common.outputs import make_dirs


def subset_dir(out: Path, domain: str, frame: int, per_subset: int) -> Path:
    k = frame // per_subset + 1
    return Path(out) / domain / f"{domain}_{k}"


def frame_paths(out: Path, domain: str, frame: int, per_subset: int) -> dict[str, Path]:
    sub = subset_dir(out, domain, frame, per_subset)
    n = frame
    return {
        "images": sub / "images" / f"Image{n}" / f"Image{n}.png",
        "masks": sub / "masks" / f"Image{n}" / f"Segmentation{n}.png",
        "depths": sub / "depths" / f"Image{n}" / f"Depth{n}.png",
    }


def frame_done(paths: dict[str, Path]) -> bool:
    return all(p.is_file() for p in paths.values())


def encode_frame(frame) -> dict[str, bytes]:
    import cv2

    params = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
    ok1, rgb = cv2.imencode(".png", np.ascontiguousarray(frame.rgb[:, :, ::-1]), params)
    ok2, mask = cv2.imencode(".png", frame.mask.astype(np.uint8) * 255, params)
    mm = np.clip(np.round(frame.depth.astype(np.float64) * 1000.0), 0, 65535).astype(np.uint16)
    ok3, depth = cv2.imencode(".png", mm, params)
    if not (ok1 and ok2 and ok3):
        raise RuntimeError("PNG encoding failed")
    return {"images": rgb.tobytes(), "masks": mask.tobytes(), "depths": depth.tobytes()}


def write_frame(paths: dict[str, Path], data: dict[str, bytes]) -> None:
    """Write one frame so that no reader ever sees part of it.

    Each file is written into a hidden staging folder beside its `ImageN/` folder, which is
    then renamed into place (a rename is atomic): `ImageN/` appears complete or not at all.
    Depth and mask go first, the RGB image last. Unlike `segmin.common.atomic`, the files are not
    fsync'ed one by one: three fsyncs per frame cost more than rendering it, and what they
    protect against (power loss, not a killed process) a rerun repairs by re-rendering frames
    whose files fail to decode. Files replaced in an existing folder go through `segmin.common.atomic`.
    """
    for kind in ("depths", "masks", "images"):
        final = paths[kind]
        folder = final.parent
        if folder.is_dir():  # a previous run (or --overwrite): replace the file in place
            write_bytes(final, data[kind])
            continue
        make_dirs(folder.parent)
        staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".staging", dir=folder.parent))
        try:
            with open(staging / final.name, "wb") as handle:
                handle.write(data[kind])
            os.rename(staging, folder)
        except OSError:
            if folder.is_dir():  # lost a race with another writer of the same frame: same bytes
                shutil.rmtree(staging, ignore_errors=True)
            else:
                raise


def clean_stale(out: Path, domain: str, owns) -> int:
    """Remove staging folders and temporary files left by a killed run (own frames only)."""
    removed = 0
    root = Path(out) / domain
    if not root.is_dir():
        return 0
    for kind_dir in root.glob(f"{domain}_*/*"):
        if not kind_dir.is_dir():
            continue
        for entry in kind_dir.iterdir():
            name = entry.name
            frame = _frame_of(name)
            if frame is None or not owns(frame):
                continue
            if name.startswith(".") and name.endswith(".staging"):
                shutil.rmtree(entry, ignore_errors=True)
                removed += 1
            elif entry.is_dir():
                for tmp in entry.glob(".*.tmp"):
                    tmp.unlink(missing_ok=True)
                    removed += 1
    return removed


def _frame_of(name: str) -> int | None:
    core = name.lstrip(".")
    if not core.startswith("Image"):
        return None
    digits = ""
    for ch in core[5:]:
        if not ch.isdigit():
            break
        digits += ch
    return int(digits) if digits else None
