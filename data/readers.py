"""Read dataset files: RGB images, binary masks, depth in metres; every failure names the file.

libjpeg and libpng decode truncated files with only a warning, so the end markers are checked
before decoding: a half-copied dataset fails loudly instead of training on grey stripes. This is
the one RGB reader of the project (export verification and the pipeline's timing use it too).
No torch here: the robot runtime may import it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from segmin.data.frames import DatasetError, Frame

_PNG_END = b"IEND\xaeB`\x82"
# Float depth is metres. No camera used for row following reads beyond a few hundred metres, while a
# millimetre map of any scene deeper than one metre holds values above 1000: such a file is refused
# instead of being read as kilometres of empty view (SegMinD would then see no near vegetation).
MAX_DEPTH_M = 1000.0


def _read_bytes_checked(path: Path) -> bytes:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read ({exc})") from exc
    if not data:
        raise DatasetError(f"{path}: empty file")
    suffix = path.suffix.lower()
    # libjpeg and libpng decode truncated files with only a warning; check the end markers.
    if suffix == ".png" and not data.rstrip(b"\x00").endswith(_PNG_END):
        raise DatasetError(f"{path}: truncated PNG (no IEND chunk)")
    if suffix in (".jpg", ".jpeg") and not data.rstrip(b"\x00\r\n ").endswith(b"\xff\xd9"):
        raise DatasetError(f"{path}: truncated JPEG (no end-of-image marker)")
    return data


def _decode(path: Path, flags: int, what: str) -> np.ndarray:
    """The checked bytes of `path` decoded by OpenCV; DatasetError "<path>: unreadable <what>" if not."""
    import cv2

    decoded = cv2.imdecode(np.frombuffer(_read_bytes_checked(path), np.uint8), flags)
    if decoded is None:
        raise DatasetError(f"{path}: unreadable {what}")
    return decoded


def read_image(path: str | Path) -> np.ndarray:
    """RGB uint8 H x W x 3; raises DatasetError naming the file when unreadable or truncated."""
    import cv2

    return cv2.cvtColor(_decode(Path(path), cv2.IMREAD_COLOR, "image"), cv2.COLOR_BGR2RGB)


def read_mask(path: str | Path) -> np.ndarray:
    """Binary uint8 H x W (1 = crop): single channel or RGB(A), any non-zero value is crop."""
    import cv2

    mask = _decode(Path(path), cv2.IMREAD_UNCHANGED, "mask")
    if mask.ndim == 3:
        mask = mask[..., :3].max(axis=2) if mask.shape[2] >= 3 else mask[..., 0]
    return (mask > 0).astype(np.uint8)


def check_depth_metres(depth: np.ndarray, source: str) -> None:
    """Float depth must be metres: DatasetError naming `source` and the finite range when it reaches
    above `MAX_DEPTH_M` (a millimetre map saved as float). Non-finite pixels are not looked at."""
    finite = depth[np.isfinite(depth)]
    if finite.size and float(finite.max()) > MAX_DEPTH_M:
        raise DatasetError(
            f"{source}: float depth must be metres, but its values range from {float(finite.min()):g} to "
            f"{float(finite.max()):g} (above {MAX_DEPTH_M:g} m: millimetres? divide by 1000, or save uint16 "
            "millimetre PNGs)"
        )


def read_depth(path: str | Path) -> np.ndarray:
    """Depth in metres, float32 H x W (0 = invalid). Integer PNG/TIFF hold millimetres; EXR and float
    TIFF hold metres (checked: `check_depth_metres`)."""
    import cv2

    path = Path(path)
    if path.suffix.lower() == ".exr":
        os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
        if depth is None:
            raise DatasetError(
                f"{path}: cannot read EXR depth (this OpenCV build may lack OpenEXR; set "
                "OPENCV_IO_ENABLE_OPENEXR=1 before starting Python, or convert to uint16 mm PNG)"
            )
        depth = depth[..., 0] if depth.ndim == 3 else depth
        check_depth_metres(depth, str(path))
        return np.nan_to_num(depth.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    depth = _decode(path, cv2.IMREAD_UNCHANGED, "depth image")
    depth = depth[..., 0] if depth.ndim == 3 else depth
    if depth.dtype.kind == "f":
        check_depth_metres(depth, str(path))
        return depth.astype(np.float32)
    return depth.astype(np.float32) / 1000.0


def load_frame(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """(RGB uint8 HxWx3, mask uint8 HxW of 0/1); size mismatch is an error naming both files."""
    image = read_image(frame.image_path)
    mask = read_mask(frame.mask_path)
    if image.shape[:2] != mask.shape[:2]:
        raise DatasetError(
            f"{frame.mask_path}: mask size {mask.shape[1]}x{mask.shape[0]} does not match image "
            f"{frame.image_path} size {image.shape[1]}x{image.shape[0]}"
        )
    return image, mask
