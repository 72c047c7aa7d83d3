"""Segmentation quality of a model on labelled photos: `segmin eval-seg` and the pipeline's real-eval.

Synthetic validation IoU says how well a model fits the rendered worlds; only labelled real
photos say whether it transfers. This module scores an exported ONNX file (what the robot runs)
or a training checkpoint (`predictor`) on any set the AgriSeg loader reads (AgriSeg layouts, or
a flat `images/` + `masks/` folder such as the shipped `data/real/vineyard_rows`), counting
pixels per photo with `segmin.common.seg_metrics` (`summary` derives the figures), scores where
each mask would steer (`steering`, with the set's drivable strips from `strips`) and what it
paints on uniform frames (`blank_frames`), and picks the photos of the contact sheet (`sheet`)
that shows where it fails; `results` writes the files.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from segmin.common.mask_closing import canopy_region, check_closing_radius
from segmin.common.seg_metrics import confusion
from segmin.data.agriseg_loader import DatasetError, Frame, find_frames, load_frame
from segmin.nav_eval.seg_eval.blank_frames import blank_frame_shares
from segmin.nav_eval.seg_eval.predictor import Predictor, load_predictor
from segmin.nav_eval.seg_eval.sheet import SHEET_MAX_ROWS, contact_sheet, sheet_picks, sheet_row
from segmin.nav_eval.seg_eval.steering import photo_steering
from segmin.nav_eval.seg_eval.strips import find_strips, read_strip
from segmin.nav_eval.seg_eval.summary import EvalSummary, ImageResult


def load_labelled_frames(data: str | Path) -> list[Frame]:
    """Every labelled frame the AgriSeg loader finds under `data`; its problems as one line."""
    root = Path(data)
    if not root.exists():
        raise FileNotFoundError(f"{root}: evaluation data folder not found")
    try:
        frames = find_frames(root)
    except DatasetError as exc:
        raise DatasetError(one_line(exc)) from None
    if not frames:
        raise DatasetError(f"{root}: no labelled images found")
    return frames


def one_line(exc: BaseException) -> str:
    """The loader lists problems one per line; the command prints one line (a lone problem as is)."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    if len(lines) == 2 and lines[0].endswith(": 1 problem(s):"):
        return lines[1]
    return " ".join([*lines[:1], "; ".join(lines[1:])]) if len(lines) > 1 else (lines[0] if lines else repr(exc))


def frame_name(frame: Frame, flat: bool) -> str:
    """A flat set's stem; `domain/subset/id` when the set has several."""
    return frame.image_path.stem if flat else f"{frame.domain}/{frame.subset}/{frame.frame_id}"


def evaluate(
    predictor: Predictor,
    frames: Sequence[Frame],
    data_root: str | Path,
    *,
    progress: bool = False,
    sheet_rows: int = SHEET_MAX_ROWS,
    truth_closing: int = 0,
) -> tuple[EvalSummary, np.ndarray | None]:
    """Score every frame; returns the summary and a contact sheet of up to `sheet_rows` evenly spaced frames.

    Each photo gets its IoU counts and its steering figures (`steering`: where the model's mask
    would steer against where the truth's would, and the drivable strip when the set labels one);
    the summary also holds the share the model paints of uniform frames (`blank_frames`).

    `truth_closing` > 0 scores against the canopy region (`data.canopy_region`, the truth closed
    with a disc of that radius) instead of the exact mask: on rendered frames of sparse leaves
    the exact mask calls every gap between leaves background, which a model trained on the
    canopy region (`data.label_closing`) paints by design, so only the closed truth separates
    its real errors from that difference of definition.
    """
    check_closing_radius(truth_closing, "truth closing radius")
    root = Path(data_root)
    summary = EvalSummary(
        model=str(predictor.path),
        data=str(root),
        kind=predictor.kind,
        threshold=predictor.threshold,
        input_size=predictor.input_size,
        truth_closing=truth_closing,
    )
    flat = len({(f.domain, f.subset) for f in frames}) == 1
    strip_files = find_strips(root, list(frames))
    picks = sheet_picks(len(frames), sheet_rows)
    rows: list[np.ndarray] = []
    for index, frame in enumerate(_progress(frames, progress, "eval-seg")):
        image, truth = load_frame(frame)
        truth = canopy_region(truth, truth_closing)
        strip = read_strip(strip_files[frame.image_path], truth.shape) if frame.image_path in strip_files else None
        _, prediction = predictor.predict(image)
        result = ImageResult(
            name=frame_name(frame, flat),
            image=_relative(frame.image_path, root),
            mask=_relative(frame.mask_path, root),
            width=int(image.shape[1]),
            height=int(image.shape[0]),
            counts=confusion(prediction, truth),
            steering=photo_steering(prediction, truth.astype(bool), strip),
        )
        summary.images.append(result)
        if index in picks:
            rows.append(sheet_row(image, prediction, truth.astype(bool), result))
    summary.blank_frames = blank_frame_shares(predictor)
    sheet = contact_sheet(rows, summary) if rows else None
    return summary, sheet


def evaluate_model(
    model: str | Path,
    data: str | Path,
    *,
    threshold: float | None = None,
    size: int | None = None,
    threads: int = 2,
    progress: bool = False,
    truth_closing: int = 0,
) -> tuple[EvalSummary, np.ndarray | None]:
    """`load_predictor` + `load_labelled_frames` + `evaluate` (data is checked first: it is cheaper)."""
    frames = load_labelled_frames(data)
    predictor = load_predictor(model, threshold=threshold, size=size, threads=threads)
    return evaluate(predictor, frames, data, progress=progress, truth_closing=truth_closing)


def _relative(path: Path, root: Path) -> str:
    try:
        return path.relative_to(root).as_posix()
    except ValueError:
        return str(path)


def _progress(items: Sequence[Frame], enabled: bool, label: str) -> Iterable[Frame]:
    """tqdm when asked for and installed (it is in the sim/train extras, not the robot runtime)."""
    if not enabled:
        return items
    try:
        from tqdm import tqdm
    except ImportError:
        return items
    return tqdm(items, desc=label, unit="image", leave=False)
