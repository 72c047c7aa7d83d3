"""Segmentation quality of a model on labelled photos: `segmin eval-seg` and the pipeline's real-eval.

Synthetic validation IoU says how well a model fits the rendered worlds; only labelled real
photos say whether it transfers. This module scores an exported ONNX file (what the robot runs)
or a training checkpoint on any set the AgriSeg loader reads (AgriSeg layouts, or a flat
`images/` + `masks/` folder such as the shipped `data/real/vineyard_rows`), and draws a contact
sheet that shows where it fails.

Preprocessing is the deployed one for both kinds of model: the photo is resized to the model
input with the `export.verify` rule (INTER_AREA when shrinking, INTER_LINEAR when enlarging, the
same as `nav_eval.segmenter.OnnxSegmenter`), the uint8 RGB batch goes through the ONNX graph or
through `export.onnx.DeployWrapper` (which does /255 and ImageNet normalisation exactly like the
graph), and the probability is resized back bilinearly to the photo size and thresholded there
(`>= threshold`, as the segmenter does). Metrics are computed at the ground-truth resolution.

Definitions (per image, and pooled = the same formula on pixel counts summed over the set):
- IoU = TP / (TP + FP + FN); an image with empty ground truth and an empty prediction scores 1.0
  (nothing to find, nothing claimed: a perfect answer, as in `train.metrics`).
- precision = TP / (TP + FP): undefined (NaN, written "n/a" / null) when nothing is predicted.
- recall = TP / (TP + FN): undefined (NaN) when the ground truth is empty.
- pixel accuracy = (TP + TN) / pixels.
`mean_iou` is the mean of the per-image IoUs (every image weighs the same); the pooled figures
stay defined whenever any pixel is predicted (precision) or labelled (recall), however many
single images are undefined.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.atomic import write_bytes, write_json, write_text
from segmin.common.outputs import check_results_absent
from segmin.data.agriseg_loader import DatasetError, Frame, find_frames, load_frame
from segmin.data.overlay import tint_mask
from segmin.export import metadata as md

log = logging.getLogger(__name__)

RESULT_FILES: tuple[str, ...] = ("results.csv", "results.json", "contact_sheet.png")
ONNX_SUFFIXES = (".onnx",)
CHECKPOINT_SUFFIXES = (".pt", ".pth", ".ckpt")

# Contact-sheet colours (RGB): right crop, false crop, missed crop.
TRUE_CROP = (0, 200, 0)
FALSE_CROP = (230, 0, 0)
MISSED_CROP = (0, 90, 255)
SHEET_ROW_HEIGHT = 200
SHEET_MAX_ROWS = 24


# ----------------------------------------------------------------------------- metrics


@dataclass(frozen=True)
class PixelCounts:
    """Confusion counts of the crop class; every metric is derived from these."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0

    def __add__(self, other: PixelCounts) -> PixelCounts:
        return PixelCounts(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn, self.tn + other.tn)

    @property
    def pixels(self) -> int:
        return self.tp + self.fp + self.fn + self.tn

    @property
    def iou(self) -> float:
        union = self.tp + self.fp + self.fn
        return self.tp / union if union else 1.0  # empty truth, empty prediction: perfect

    @property
    def precision(self) -> float:
        predicted = self.tp + self.fp
        return self.tp / predicted if predicted else math.nan  # nothing predicted: undefined

    @property
    def recall(self) -> float:
        actual = self.tp + self.fn
        return self.tp / actual if actual else math.nan  # nothing to find: undefined

    @property
    def pixel_accuracy(self) -> float:
        return (self.tp + self.tn) / self.pixels if self.pixels else math.nan

    def metrics(self) -> dict[str, float]:
        return {
            "iou": self.iou,
            "precision": self.precision,
            "recall": self.recall,
            "pixel_accuracy": self.pixel_accuracy,
        }


def confusion(prediction: np.ndarray, truth: np.ndarray) -> PixelCounts:
    """Counts of two same-shape masks (anything non-zero is crop); a shape mismatch is an error."""
    if prediction.shape != truth.shape:
        raise ValueError(f"prediction shape {prediction.shape} differs from the ground truth {truth.shape}")
    pred, gt = np.asarray(prediction, bool), np.asarray(truth, bool)
    tp = int(np.count_nonzero(pred & gt))
    fp = int(np.count_nonzero(pred & ~gt))
    fn = int(np.count_nonzero(~pred & gt))
    return PixelCounts(tp, fp, fn, int(pred.size) - tp - fp - fn)


@dataclass
class ImageResult:
    """One photo's counts and where it came from."""

    name: str
    image: str
    mask: str
    width: int
    height: int
    counts: PixelCounts

    def row(self) -> dict[str, Any]:
        c = self.counts
        return {
            "name": self.name,
            "image": self.image,
            "mask": self.mask,
            "width": self.width,
            "height": self.height,
            "gt_pixels": c.tp + c.fn,
            "pred_pixels": c.tp + c.fp,
            "tp": c.tp,
            "fp": c.fp,
            "fn": c.fn,
            "tn": c.tn,
            **c.metrics(),
        }


@dataclass
class EvalSummary:
    """The whole set: per-image results and the summary figures."""

    model: str
    data: str
    kind: str  # "onnx" or "checkpoint"
    threshold: float
    input_size: tuple[int, int]
    images: list[ImageResult] = field(default_factory=list)

    @property
    def pooled(self) -> PixelCounts:
        total = PixelCounts()
        for result in self.images:
            total = total + result.counts
        return total

    @property
    def mean_iou(self) -> float:
        return float(np.mean([r.counts.iou for r in self.images])) if self.images else math.nan

    def figures(self) -> dict[str, Any]:
        """The summary numbers (pooled precision/recall stay defined when single images are not)."""
        pooled = self.pooled
        defined_p = [r.counts.precision for r in self.images if not math.isnan(r.counts.precision)]
        defined_r = [r.counts.recall for r in self.images if not math.isnan(r.counts.recall)]
        return {
            "images": len(self.images),
            "mean_iou": self.mean_iou,
            "pooled_iou": pooled.iou,
            "precision": pooled.precision,
            "recall": pooled.recall,
            "pixel_accuracy": pooled.pixel_accuracy,
            "mean_precision": float(np.mean(defined_p)) if defined_p else math.nan,
            "mean_recall": float(np.mean(defined_r)) if defined_r else math.nan,
            "images_without_prediction": len(self.images) - len(defined_p),
            "images_without_crop": len(self.images) - len(defined_r),
        }

    def as_dict(self) -> dict[str, Any]:
        return {
            "format": "segmin-seg-eval-v1",
            "model": self.model,
            "data": self.data,
            "kind": self.kind,
            "threshold": self.threshold,
            "input_size": list(self.input_size),
            "summary": _json_safe(self.figures()),
            "definitions": DEFINITIONS,
            "rows": [_json_safe(r.row()) for r in self.images],
        }

    def summary_lines(self) -> list[str]:
        """What the command prints: one line per figure."""
        f = self.figures()
        h, w = self.input_size
        lines = [
            f"{self.model} ({self.kind}, input {h}x{w}, threshold {self.threshold:g}) on {self.data}: "
            f"{f['images']} images",
            f"  mean IoU over images  {fmt(f['mean_iou'])}",
            f"  pooled IoU            {fmt(f['pooled_iou'])}",
            f"  precision (pooled)    {fmt(f['precision'])}",
            f"  recall (pooled)       {fmt(f['recall'])}",
            f"  pixel accuracy        {fmt(f['pixel_accuracy'])}",
        ]
        if f["images_without_prediction"]:
            lines.append(f"  {f['images_without_prediction']} image(s) with no crop predicted: precision n/a there")
        if f["images_without_crop"]:
            lines.append(f"  {f['images_without_crop']} image(s) with no crop in the ground truth: recall n/a there")
        return lines


DEFINITIONS = {
    "iou": "TP / (TP + FP + FN); 1.0 when the ground truth and the prediction are both empty",
    "precision": "TP / (TP + FP); null (n/a) when nothing is predicted",
    "recall": "TP / (TP + FN); null (n/a) when the ground truth is empty",
    "pixel_accuracy": "(TP + TN) / pixels",
    "mean_iou": "mean of the per-image IoUs",
    "pooled": "pooled_iou, precision, recall, pixel_accuracy: the same formulas on counts summed over all images",
    "resolution": "prediction resized (bilinear probability) to the ground-truth mask size, then thresholded",
}


def fmt(value: float | None) -> str:
    """A figure for people: three decimals, or n/a when undefined."""
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.3f}"


def _json_safe(values: dict[str, Any]) -> dict[str, Any]:
    """NaN is not JSON: undefined figures become null."""
    return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in values.items()}


# ----------------------------------------------------------------------------- models


@dataclass
class Predictor:
    """A model reduced to what evaluation needs: uint8 1 x h x w x 3 batch -> h x w probability."""

    path: Path
    kind: str
    input_size: tuple[int, int]
    threshold: float
    model_probabilities: Callable[[np.ndarray], np.ndarray]

    def predict(self, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(probability float32 H x W, mask bool H x W) at the photo size (see module docstring)."""
        import cv2

        from segmin.data.model_input import resize_to_input

        batch = resize_to_input(np.ascontiguousarray(rgb), self.input_size)[None]
        probs = np.asarray(self.model_probabilities(batch), np.float32).reshape(self.input_size)
        height, width = rgb.shape[:2]
        if probs.shape != (height, width):
            probs = cv2.resize(probs, (width, height), interpolation=cv2.INTER_LINEAR)
        probs = np.clip(probs, 0.0, 1.0)
        return probs, probs >= self.threshold


def load_predictor(
    model: str | Path, *, threshold: float | None = None, size: int | None = None, threads: int = 2
) -> Predictor:
    """An exported `.onnx` (onnxruntime, size and threshold from its metadata) or a `.pt` checkpoint.

    `threshold` overrides the model's; `size` sets a checkpoint's square input size (an ONNX
    graph's input size is fixed, so a different `size` is an error rather than silently ignored).
    """
    path = Path(model)
    if not path.exists():
        raise FileNotFoundError(f"{path}: model file not found")
    if not path.is_file():
        raise ValueError(f"{path}: model is not a file (expected an exported .onnx or a checkpoint .pt)")
    if threshold is not None and not 0.0 < float(threshold) < 1.0:
        raise ValueError(f"--threshold {threshold}: must be in (0, 1)")
    if size is not None and int(size) < 32:
        raise ValueError(f"--size {size}: must be at least 32 px")
    suffix = path.suffix.lower()
    if suffix in ONNX_SUFFIXES:
        predictor = _onnx_predictor(path, threads, size)
    elif suffix in CHECKPOINT_SUFFIXES:
        predictor = _checkpoint_predictor(path, size)
    else:
        raise ValueError(
            f"{path}: unknown model type {suffix or '(no suffix)'!r}; expected an exported .onnx "
            f"or a training checkpoint ({', '.join(CHECKPOINT_SUFFIXES)})"
        )
    if threshold is not None:
        predictor.threshold = float(threshold)
    return predictor


def _onnx_predictor(path: Path, threads: int, size: int | None) -> Predictor:
    from segmin.export.verify import make_session, run_session

    try:
        session = make_session(path, threads=threads, spin=False)
    except Exception as exc:  # onnxruntime raises its own types for unparsable files
        raise ValueError(f"{path}: not a loadable ONNX model ({str(exc).splitlines()[0][:300]})") from exc
    meta = dict(session.get_modelmeta().custom_metadata_map)
    md.check_metadata(meta, str(path))
    input_size = md.parse_input_size(meta[md.KEY_INPUT_SIZE])
    if size is not None and (int(size), int(size)) != input_size:
        raise ValueError(
            f"--size {size}: {path} has a fixed {input_size[0]}x{input_size[1]} input (--size applies to checkpoints)"
        )
    inputs = session.get_inputs()
    if len(inputs) != 1 or inputs[0].type != "tensor(uint8)":
        raise ValueError(f"{path}: expected one uint8 RGB input, got {[(i.name, i.type) for i in inputs]}")
    if list(inputs[0].shape)[1:] != [input_size[0], input_size[1], 3]:
        raise ValueError(
            f"{path}: input shape {list(inputs[0].shape)} does not match metadata "
            f"{md.KEY_INPUT_SIZE}={md.format_input_size(input_size)}"
        )

    def probabilities(batch: np.ndarray) -> np.ndarray:
        return run_session(session, batch, batch=1)[0, 0]

    return Predictor(path, "onnx", input_size, float(meta[md.KEY_THRESHOLD]), probabilities)


def _checkpoint_predictor(path: Path, size: int | None) -> Predictor:
    from segmin.export.onnx import DeployWrapper
    from segmin.export.verify import torch_reference
    from segmin.models.checkpoint import load_model  # torch.load(weights_only=True)

    try:
        model, info = load_model(path)
    except ValueError as exc:  # torch's unpickler explains itself over several lines: keep the first
        first = str(exc).splitlines()[0].rstrip()
        raise ValueError(first + (" ...)" if first.count("(") > first.count(")") else "")) from exc
    input_size = (int(size), int(size)) if size is not None else tuple(int(v) for v in info["input_size"])
    reference = torch_reference(DeployWrapper(model).eval())

    def probabilities(batch: np.ndarray) -> np.ndarray:
        return reference(batch)[0, 0]

    return Predictor(path, "checkpoint", input_size, float(info.get("threshold", 0.5)), probabilities)  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- evaluation


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
    return " ".join(lines[:1] + ["; ".join(lines[1:])]) if len(lines) > 1 else (lines[0] if lines else repr(exc))


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
) -> tuple[EvalSummary, np.ndarray | None]:
    """Score every frame; returns the summary and a contact sheet of up to `sheet_rows` evenly spaced frames."""
    root = Path(data_root)
    summary = EvalSummary(
        model=str(predictor.path),
        data=str(root),
        kind=predictor.kind,
        threshold=predictor.threshold,
        input_size=tuple(predictor.input_size),
    )  # type: ignore[arg-type]
    flat = len({(f.domain, f.subset) for f in frames}) == 1
    picks = (
        set(np.linspace(0, len(frames) - 1, min(sheet_rows, len(frames))).round().astype(int).tolist())
        if sheet_rows > 0 and frames
        else set()
    )
    rows: list[np.ndarray] = []
    for index, frame in enumerate(_progress(frames, progress, "eval-seg")):
        image, truth = load_frame(frame)
        _, prediction = predictor.predict(image)
        result = ImageResult(
            name=frame_name(frame, flat),
            image=_relative(frame.image_path, root),
            mask=_relative(frame.mask_path, root),
            width=int(image.shape[1]),
            height=int(image.shape[0]),
            counts=confusion(prediction, truth),
        )
        summary.images.append(result)
        if index in picks:
            rows.append(sheet_row(image, prediction, truth.astype(bool), result))
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
) -> tuple[EvalSummary, np.ndarray | None]:
    """`load_predictor` + `load_labelled_frames` + `evaluate` (data is checked first: it is cheaper)."""
    frames = load_labelled_frames(data)
    predictor = load_predictor(model, threshold=threshold, size=size, threads=threads)
    return evaluate(predictor, frames, data, progress=progress)


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


# ----------------------------------------------------------------------------- outputs


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
        writer.writerow({k: (_csv_value(v)) for k, v in row.items()})
    paths = {"csv": out / "results.csv", "json": out / "results.json"}
    write_text(paths["csv"], buffer.getvalue())
    write_json(paths["json"], summary.as_dict())
    if sheet is not None:
        paths["contact_sheet"] = out / "contact_sheet.png"
        write_png(paths["contact_sheet"], sheet)
    return {k: str(v) for k, v in paths.items()}


def _csv_value(value: Any) -> Any:
    if isinstance(value, float):
        return "n/a" if math.isnan(value) else f"{value:.6g}"
    return value


def write_png(path: Path, rgb: np.ndarray) -> None:
    import cv2

    ok, png = cv2.imencode(".png", np.ascontiguousarray(rgb[:, :, ::-1]))
    if not ok:
        raise RuntimeError(f"{path}: PNG encoding failed")
    write_bytes(path, png.tobytes())


def read_summary(path: str | Path) -> dict[str, Any]:
    """results.json back (for reports built from cached stages)."""
    return json.loads(Path(path).read_text())


# ----------------------------------------------------------------------------- contact sheet


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
        f"{result.name}   IoU {fmt(c.iou)}   precision {fmt(c.precision)}   recall {fmt(c.recall)}",
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
        f"{fmt(f['mean_iou'])}, pooled IoU {fmt(f['pooled_iou'])}, P {fmt(f['precision'])}, R {fmt(f['recall'])}"
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
