"""Camera-view videos without matplotlib: the overlay drawn on each frame and the MP4/GIF writer.

Used by nav-eval (`--video`) and by `segmin replay`, which runs on the bare robot install.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from segmin.common.atomic import atomic_path, write_bytes
from segmin.data.overlay import GREEN, tint_mask


def overlay(rgb: np.ndarray, mask: np.ndarray | None, column: float | None) -> np.ndarray:
    """Camera view with the mask tinted green and the chosen column drawn in red."""
    img = np.asarray(rgb, dtype=np.uint8).copy() if mask is None else tint_mask(rgb, mask, GREEN, opacity=0.45)
    if column is not None and np.isfinite(column):
        c = int(round(float(column)))
        c = min(max(c, 0), img.shape[1] - 1)
        img[:, max(c - 1, 0) : c + 1] = (255, 0, 0)
    else:
        img[:4, :] = (255, 0, 0)  # no valid command: red bar at the top
    return img


class _NoMp4Encoder(Exception):
    """OpenCV here cannot write MP4; raised inside `atomic_path` so its temporary file is removed."""


def _write_mp4(path: Path, frames: list[np.ndarray], fps: float) -> None:
    import cv2

    height, width = np.asarray(frames[0]).shape[:2]
    with atomic_path(path, suffix=".mp4") as tmp:  # VideoWriter picks the container from the name
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter.fourcc(*"mp4v"), float(fps), (width, height))
        if not writer.isOpened():
            raise _NoMp4Encoder(path)
        for frame in frames:
            writer.write(cv2.cvtColor(np.asarray(frame, dtype=np.uint8), cv2.COLOR_RGB2BGR))
        writer.release()
        if tmp.stat().st_size == 0:
            raise _NoMp4Encoder(path)


def write_video(path: str | Path, frames: list[np.ndarray], fps: float = 5.0) -> Path:
    """The camera view as MP4 (OpenCV, mp4v) or, when the suffix is .gif or MP4 cannot be
    written, an animated GIF (Pillow). Written atomically; returns the path actually written."""
    path = Path(path)
    if not frames:
        return path
    sizes = sorted({np.asarray(f).shape[:2] for f in frames})
    if len(sizes) > 1:  # OpenCV's VideoWriter silently drops every frame not of the first one's size
        raise ValueError(f"{path}: video frames of {len(sizes)} sizes {sizes}; a video needs one frame size")
    if path.suffix.lower() == ".mp4":
        try:
            _write_mp4(path, frames, fps)
            return path
        except _NoMp4Encoder:
            path = path.with_suffix(".gif")  # no MP4 encoder here: fall back to GIF
    from PIL import Image

    images = [Image.fromarray(np.asarray(f, dtype=np.uint8)) for f in frames]
    buffer = io.BytesIO()
    images[0].save(
        buffer, format="GIF", save_all=True, append_images=images[1:], duration=int(round(1000.0 / fps)), loop=0
    )
    write_bytes(path, buffer.getvalue())
    return path
