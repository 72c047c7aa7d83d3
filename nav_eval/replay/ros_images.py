"""ROS image messages -> the arrays the runtime takes, for bag replay and the ROS 2 node alike.

One decoder for both, so a bag replayed offline and the same bag played to the node hand the
runtime the same pixels. Messages are read by their fields only (`header.stamp.sec`,
`encoding`, `height`, `width`, `step`, `is_bigendian`, `data`; `format` for a
`CompressedImage`), so the objects of `rosbags` and of rclpy both work, and nothing here
imports either (this module is part of the bare robot install: numpy and OpenCV only).

- colour: `Image` rgb8 / bgr8 / rgba8 / bgra8, or `CompressedImage` jpeg / png -> RGB uint8;
- depth: `Image` 16UC1 (millimetres; mono16 alike) or 32FC1 (metres: values above
  `MAX_DEPTH_M` are refused as millimetres, as replay's folder reader refuses them), `CompressedImage` png
  (16-bit millimetres) or `compressedDepth` png (image_transport's: a 12-byte header, then a
  PNG of millimetres, or for 32FC1 of quantised inverse depth) -> float32 metres, 0 = no
  reading (REP 118's NaN / inf readings become 0, and the caller is told).

A message that cannot be decoded raises `ImageMessageError` naming the topic and the problem.
A `CameraInfo` gives the camera's intrinsics (`camera_from_info`), which SegCorridor needs.
"""

from __future__ import annotations

import functools
import math
import struct
from typing import Any

import numpy as np

from segmin.data.frames import DatasetError
from segmin.data.readers import check_depth_metres
from segmin.nav_eval.runtime.camera import CameraGeometry
from segmin.nav_eval.runtime.follower_config import CameraConfig
from segmin.nav_eval.runtime.navigator import to_metres

DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")
# image_transport's compressedDepth header: int32 format, then the two floats of the inverse-depth quantisation.
COMPRESSED_DEPTH_HEADER = struct.Struct("<iff")


class ImageMessageError(ValueError):
    """A message that is not an image the runtime can use (one line: the topic and the problem)."""


def camera_from_info(message: Any, topic: str, mount: CameraConfig) -> CameraGeometry:
    """The camera of a `CameraInfo` message (`k`, `width`, `height`) on `mount` (the mount is in no
    message: the follower config's). ValueError naming `topic`."""
    k = np.asarray(message.k, dtype=float).reshape(-1)
    if k.size != 9 or not np.isfinite(k).all():
        raise ValueError(f"{topic}: k is not a finite 3 x 3 matrix")
    try:
        return mount.mounted(
            width=int(message.width),
            height=int(message.height),
            fx=float(k[0]),
            fy=float(k[4]),
            cx=float(k[2]),
            cy=float(k[5]),
        )
    except ValueError as exc:
        raise ValueError(f"{topic}: {exc} (an uncalibrated camera publishes zeros)") from None


@functools.cache
def _colour_encodings() -> dict[str, tuple[int, int | None]]:
    """Colour encoding -> (channels, OpenCV conversion to RGB or None)."""
    import cv2

    return {
        "rgb8": (3, None),
        "bgr8": (3, cv2.COLOR_BGR2RGB),
        "rgba8": (4, cv2.COLOR_RGBA2RGB),
        "bgra8": (4, cv2.COLOR_BGRA2RGB),
    }


def stamp_seconds(message: Any) -> float:
    """The header stamp in seconds (the runtime's time base)."""
    stamp = message.header.stamp
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def is_compressed(message: Any) -> bool:
    """A `CompressedImage` (it has `format`), not an `Image`."""
    return hasattr(message, "format")


def _raw_bytes(message: Any) -> np.ndarray:
    data = message.data
    try:
        return np.frombuffer(data, dtype=np.uint8)
    except TypeError:  # a plain list of ints
        return np.asarray(data, dtype=np.uint8)


def _pixels(message: Any, topic: str, channels: int, dtype: np.dtype) -> np.ndarray:
    """The (H, W[, C]) array of an `Image`, honouring its row stride and byte order."""
    height, width, step = int(message.height), int(message.width), int(message.step)
    row = width * channels * dtype.itemsize
    if height < 1 or width < 1:
        raise ImageMessageError(f"{topic}: image is {width}x{height}")
    if step < row:
        raise ImageMessageError(f"{topic}: step {step} is shorter than a row of {width} x {message.encoding} ({row})")
    raw = _raw_bytes(message)
    if raw.size < height * step:
        raise ImageMessageError(f"{topic}: {raw.size} bytes of data for {height} rows of {step}")
    rows = raw[: height * step].reshape(height, step)[:, :row]
    big = bool(message.is_bigendian)
    pixels = np.ascontiguousarray(rows).view(dtype.newbyteorder(">" if big else "<"))
    pixels = pixels.astype(dtype, copy=False)
    return pixels.reshape(height, width) if channels == 1 else pixels.reshape(height, width, channels)


def decode_colour(message: Any, topic: str) -> np.ndarray:
    """RGB uint8 (H, W, 3) of a colour `Image` or `CompressedImage`."""
    import cv2

    if is_compressed(message):
        fmt = str(message.format).lower()
        if "compresseddepth" in fmt:
            raise ImageMessageError(f"{topic}: a compressedDepth image on the colour topic")
        image = cv2.imdecode(_raw_bytes(message), cv2.IMREAD_COLOR)
        if image is None:
            raise ImageMessageError(f"{topic}: CompressedImage ({message.format!r}) is not a JPEG or PNG OpenCV reads")
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    encodings = _colour_encodings()
    encoding = str(message.encoding)
    if encoding not in encodings:
        raise ImageMessageError(f"{topic}: colour encoding {encoding!r} (use one of {', '.join(encodings)})")
    channels, conversion = encodings[encoding]
    pixels = _pixels(message, topic, channels, np.dtype(np.uint8))
    return np.ascontiguousarray(pixels) if conversion is None else cv2.cvtColor(pixels, conversion)


def decode_depth(message: Any, topic: str) -> tuple[np.ndarray, bool]:
    """Depth in metres (float32, 0 = no reading) and whether it had non-finite pixels (set to 0)."""
    if is_compressed(message):
        return _decode_compressed_depth(message, topic), False
    encoding = str(message.encoding)
    if encoding in ("16UC1", "mono16"):
        return to_metres(_pixels(message, topic, 1, np.dtype(np.uint16))), False
    if encoding == "32FC1":
        depth = _pixels(message, topic, 1, np.dtype(np.float32))
        try:  # millimetres sent as 32FC1 would put every plant 1000 times too far: an open row
            check_depth_metres(depth, f"{topic}: 32FC1")
        except DatasetError as exc:
            raise ImageMessageError(str(exc)) from None
        bad = ~np.isfinite(depth)
        if bad.any():
            return np.where(bad, np.float32(0.0), depth), True
        return np.ascontiguousarray(depth), False
    raise ImageMessageError(f"{topic}: depth encoding {encoding!r} (use one of {', '.join(DEPTH_ENCODINGS)})")


def _decode_compressed_depth(message: Any, topic: str) -> np.ndarray:
    import cv2

    fmt = str(message.format)
    raw = _raw_bytes(message)
    quant: tuple[float, float] | None = None
    if "compresseddepth" in fmt.lower():
        if "png" not in fmt.lower():
            raise ImageMessageError(f"{topic}: compressedDepth format {fmt!r} (only png is read)")
        if raw.size <= COMPRESSED_DEPTH_HEADER.size:
            raise ImageMessageError(f"{topic}: compressedDepth message of {raw.size} bytes has no image")
        _, a, b = COMPRESSED_DEPTH_HEADER.unpack(raw[: COMPRESSED_DEPTH_HEADER.size].tobytes())
        raw = raw[COMPRESSED_DEPTH_HEADER.size :]
        if fmt.strip().startswith("32FC1"):
            quant = (a, b)
    image = cv2.imdecode(raw, cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint16 or image.ndim != 2:
        what = "no image" if image is None else f"{image.dtype} with shape {image.shape}"
        raise ImageMessageError(f"{topic}: compressed depth ({fmt!r}) must be a 16-bit one-channel PNG, got {what}")
    if quant is None:
        return to_metres(image)
    # image_transport's 32FC1 quantisation: q = a / z + b, 0 = no reading.
    a, b = quant
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ImageMessageError(f"{topic}: compressedDepth header holds non-finite quantisation ({a}, {b})")
    q = image.astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.float32(a) / (q - np.float32(b))
    return np.where((image > 0) & np.isfinite(depth) & (depth > 0), depth, np.float32(0.0)).astype(np.float32)
