"""Reading a recorded sequence for `segmin replay`: frames in time order, aligned depth, timestamps.

A folder of frames plays in natural name order: the numbers in the names compare by value, so
unpadded names (`f_0 ... f_11`) play f_0, f_1, f_2 ... f_11, not f_0, f_1, f_10, f_11, f_2 as
plain text sorting would; padded names play as before. Names that leave the order open are
refused: two files of one stem (`f_002.png` and `f_002.jpg`, one frame twice) and two names that
differ only in how a number is written (`f_01`, `f_1`). The order used is reported as a note.

Depth units by format: a uint16 PNG holds millimetres (0 = no reading); a float .npy holds metres
(non-finite = no reading; values above `MAX_DEPTH_M` are refused as millimetres saved as float).

Every file is listed and paired before the first frame runs, so a missing depth frame stops the
replay before any output is written; every frame must have the first frame's size.
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segmin.data.readers import check_depth_metres
from segmin.nav_eval.runtime.navigator import to_metres

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v")
_NUMBER = re.compile(r"(\d+)")

# One frame: (name, t in s, RGB uint8, depth in metres or None, whether the depth had non-finite pixels).
SequenceFrame = tuple[str, float, np.ndarray, np.ndarray | None, bool]


@dataclass
class RecordedSequence:
    """The frames to replay, lazily read, with their count and the order they play in."""

    count: int
    frames: Iterator[SequenceFrame]
    order: str | None = None  # how a folder's frames were ordered (None for a video)


def natural_key(stem: str) -> tuple[str | int, ...]:
    """Sort key of a name: text parts as text, digit runs as numbers (`f_2` before `f_10`)."""
    return tuple(int(part) if i % 2 else part for i, part in enumerate(_NUMBER.split(stem)))


def _by_stem(files: list[Path], flag: str, folder: Path) -> dict[str, Path]:
    """{stem: file}; two files of one stem are one frame given twice, refused naming both."""
    found: dict[str, Path] = {}
    for path in sorted(files):
        if path.stem in found:
            raise ValueError(
                f"--{flag} {folder}: {found[path.stem].name} and {path.name} are the same frame "
                f"({path.stem!r}) twice; keep one"
            )
        found[path.stem] = path
    return found


def _in_natural_order(files: list[Path], flag: str, folder: Path) -> list[Path]:
    """`files` (distinct stems) in natural name order; names that tie are refused, naming two."""
    ordered = sorted(files, key=lambda p: natural_key(p.stem))
    for before, after in itertools.pairwise(ordered):
        if natural_key(before.stem) == natural_key(after.stem):
            raise ValueError(
                f"--{flag} {folder}: {before.name} and {after.name} carry the same number, so their order "
                "is ambiguous; rename them (e.g. pad every number to the same width)"
            )
    return ordered


def _files(folder: Path, flag: str, suffixes: tuple[str, ...]) -> dict[str, Path]:
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in suffixes]
    if not files:
        raise FileNotFoundError(f"--{flag} {folder}: no image files in the folder")
    return _by_stem(files, flag, folder)


def _order_note(frames: list[Path]) -> str:
    shown = [p.name for p in frames[:3]] + (["...", frames[-1].name] if len(frames) > 3 else [])
    return f"{len(frames)} frames in natural name order (numbers by value): {', '.join(shown)}"


def _read_rgb(path: Path) -> np.ndarray:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"--rgb: cannot read {path} as an image")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def read_depth(path: Path) -> tuple[np.ndarray, bool]:
    """Depth in metres (float32) and whether it had non-finite pixels (set to 0, no reading)."""
    import cv2

    if path.suffix.lower() == ".npy":
        try:
            depth = np.load(path)
        except (OSError, ValueError) as exc:
            raise ValueError(f"--depth: cannot read {path} ({exc})") from None
        if depth.ndim != 2 or not np.issubdtype(depth.dtype, np.floating):
            raise ValueError(f"--depth: {path} must be a 2-D float array of metres, got {depth.dtype} {depth.shape}")
        check_depth_metres(depth, f"--depth: {path}")
        bad = ~np.isfinite(depth)
        if bad.any():
            depth = np.where(bad, 0.0, depth)
        return depth.astype(np.float32), bool(bad.any())
    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if depth is None:
        raise ValueError(f"--depth: cannot read {path} as an image")
    if depth.dtype != np.uint16 or depth.ndim != 2:
        raise ValueError(
            f"--depth: {path} must be a single-channel uint16 PNG of millimetres, "
            f"got {depth.dtype} with shape {depth.shape}"
        )
    return to_metres(depth), False


def _timestamps(count: int, fps: float | None, timestamps: Path | None, source_fps: float | None) -> np.ndarray:
    if fps is not None and timestamps is not None:
        raise ValueError("give --fps or --timestamps, not both")
    if timestamps is not None:
        try:
            values = [float(line) for line in Path(timestamps).read_text().split()]
        except ValueError as exc:
            raise ValueError(f"--timestamps {timestamps}: not a list of numbers ({exc})") from None
        if len(values) != count:
            raise ValueError(f"--timestamps {timestamps}: {len(values)} timestamps for {count} frames")
        return np.asarray(values, dtype=float)
    rate = fps if fps is not None else source_fps
    if rate is None:
        raise ValueError("a folder of frames needs --fps or --timestamps")
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"--fps must be a finite number > 0, got {rate!r}")
    return np.arange(count, dtype=float) / rate


def _size(image: np.ndarray) -> str:
    return f"{image.shape[1]}x{image.shape[0]}"


def _folder_sequence(rgb: Path, depth: Path | None, fps: float | None, timestamps: Path | None) -> RecordedSequence:
    frames = _in_natural_order(list(_files(rgb, "rgb", IMAGE_SUFFIXES).values()), "rgb", rgb)
    depth_files: list[Path | None] = [None] * len(frames)
    if depth is not None:
        if not depth.is_dir():
            raise FileNotFoundError(f"--depth {depth}: not a folder")
        by_stem = _files(depth, "depth", (*IMAGE_SUFFIXES, ".npy"))
        missing = [p.name for p in frames if p.stem not in by_stem]
        if missing:
            raise FileNotFoundError(
                f"--depth {depth}: no depth frame for {missing[0]}"
                + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else "")
            )
        depth_files = [by_stem[p.stem] for p in frames]
    times = _timestamps(len(frames), fps, timestamps, None)

    def read() -> Iterator[SequenceFrame]:
        first: np.ndarray | None = None
        for path, depth_path, t in zip(frames, depth_files, times):
            image = _read_rgb(path)
            first = image if first is None else first
            if image.shape[:2] != first.shape[:2]:  # the runtime and the video need one frame size
                raise ValueError(f"--rgb: {path.name} is {_size(image)}, the frames before it are {_size(first)}")
            if depth_path is None:
                yield path.name, float(t), image, None, False
                continue
            d, bad = read_depth(depth_path)
            if d.shape != image.shape[:2]:
                raise ValueError(
                    f"--depth: {depth_path.name} is {_size(d)}, the RGB frame {path.name} is {_size(image)}"
                )
            yield path.name, float(t), image, d, bad

    return RecordedSequence(len(frames), read(), _order_note(frames))


def _video_sequence(rgb: Path, fps: float | None, timestamps: Path | None) -> RecordedSequence:
    import cv2

    capture = cv2.VideoCapture(str(rgb))
    if not capture.isOpened():
        raise ValueError(f"--rgb {rgb}: OpenCV cannot open this video")
    count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
    source_fps = float(capture.get(cv2.CAP_PROP_FPS)) or None
    if count <= 0:
        capture.release()
        raise ValueError(f"--rgb {rgb}: the video has no frames OpenCV can count")
    times = _timestamps(count, fps, timestamps, source_fps)

    def read() -> Iterator[SequenceFrame]:
        try:
            for i, t in enumerate(times):
                ok, image = capture.read()
                if not ok:
                    raise ValueError(f"--rgb {rgb}: frame {i} cannot be decoded")
                yield f"{rgb.name}#{i}", float(t), cv2.cvtColor(image, cv2.COLOR_BGR2RGB), None, False
        finally:
            capture.release()

    return RecordedSequence(count, read())


def read_sequence(rgb: Path, depth: Path | None, fps: float | None, timestamps: Path | None) -> RecordedSequence:
    """The sequence a folder of frames (with optional depth folder) or a video holds; bad input is
    one line naming the argument and the file (see the module docstring)."""
    rgb = Path(rgb)
    if not rgb.exists():
        raise FileNotFoundError(f"--rgb {rgb}: no such file or folder")
    if rgb.is_dir():
        return _folder_sequence(rgb, None if depth is None else Path(depth), fps, timestamps)
    if rgb.suffix.lower() not in VIDEO_SUFFIXES:
        raise ValueError(f"--rgb {rgb}: give a folder of frames or a video ({', '.join(VIDEO_SUFFIXES)})")
    if depth is not None:
        raise ValueError("--depth goes with a folder of RGB frames; a video has no aligned depth frames")
    return _video_sequence(rgb, fps, timestamps)
