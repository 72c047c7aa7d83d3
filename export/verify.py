"""Verify an exported file before anyone deploys it: onnx.checker, then onnxruntime vs PyTorch.

The comparison runs on real frames (a folder of images, or an AgriSeg-layout dataset root), resized
to the model's input size exactly as the robot-side `OnnxSegmenter` resizes them. A file passes
when the largest absolute probability difference is <= 1e-4 and the thresholded masks agree on
>= 99.9 % of the pixels. `export.pipeline` removes a file that fails.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from segmin.common.seg_metrics import confusion
from segmin.data.agriseg_loader import find_frames
from segmin.data.model_input import resize_to_input
from segmin.data.readers import read_image

log = logging.getLogger(__name__)

MAX_ABS_DIFF = 1e-4
MIN_MASK_AGREEMENT = 0.999
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
# Folders of an AgriSeg-style layout that hold labels, not camera frames.
_NON_RGB_DIRS = {"masks", "mask", "depths", "depth", "labels", "segmentation"}


class VerificationError(ValueError):
    """The exported graph does not reproduce PyTorch within the bounds; the message says by how much."""


@dataclass(frozen=True)
class Agreement:
    """How closely one model's probabilities follow a reference's on the same frames."""

    frames: int
    max_abs_diff: float
    mean_abs_diff: float
    mask_agreement: float  # fraction of pixels whose thresholded value is the same (pixel accuracy)
    mask_iou: float  # IoU of the two vegetation masks, pooled over the frames (1.0 when both are empty)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    def summary(self) -> str:
        """One line for a file's `verification` metadata and the log."""
        return (
            f"{self.frames} frames, max|dp| {self.max_abs_diff:.2e}, "
            f"mask agreement {100 * self.mask_agreement:.3f} %, IoU {self.mask_iou:.4f}"
        )


# ----------------------------------------------------------------------------- frames


def _image_files(folder: Path) -> list[Path]:
    files = []
    for path in sorted(folder.rglob("*")):
        if path.suffix.lower() not in IMAGE_SUFFIXES or not path.is_file():
            continue
        relative_parts = {part.lower() for part in path.relative_to(folder).parts[:-1]}
        if relative_parts & _NON_RGB_DIRS:
            continue
        files.append(path)
    return files


def _agriseg_images(root: Path, domains: list[str] | None = None) -> list[Path]:
    """Image paths of an AgriSeg-layout root via data.agriseg_loader, [] when it is not one."""
    try:
        return [frame.image_path for frame in find_frames(root, domains, skip_unpaired=True)]
    except (ValueError, OSError) as exc:  # not an AgriSeg layout (or an empty one): plain folder
        log.debug("%s is not an AgriSeg layout (%s); reading it as a folder of images", root, exc)
        return []


def load_frames(
    source: str | Path, input_size: tuple[int, int], limit: int = 32, domains: list[str] | None = None
) -> np.ndarray:
    """Up to `limit` real frames from `source`, as uint8 N x H x W x 3 at the model input size.

    `source` is an AgriSeg-layout root (read with data.agriseg_loader) or any
    folder of PNG/JPG images (searched recursively; mask and depth folders are skipped);
    `domains` restricts an AgriSeg root to those domains (the training run's choice). Frames
    are picked evenly spaced over the sorted list, so the choice is deterministic.
    """
    root = Path(source)
    if not root.exists():
        raise FileNotFoundError(f"{root}: calibration/verification data folder not found")
    paths = [root] if root.is_file() else _agriseg_images(root, domains) or ([] if domains else _image_files(root))
    if not paths:
        which = f" of domains {domains}" if domains else ""
        raise ValueError(f"{root}: no images{which} ({', '.join(IMAGE_SUFFIXES)}) found to verify the export on")
    if limit < 1:
        raise ValueError(f"limit={limit}: need at least one frame")
    if len(paths) > limit:
        picks = np.linspace(0, len(paths) - 1, limit).round().astype(int)
        paths = [paths[i] for i in picks]
    frames = [resize_to_input(read_image(path), input_size) for path in paths]
    return np.stack(frames).astype(np.uint8, copy=False)


# ----------------------------------------------------------------------------- comparisons


def compare(probs: np.ndarray, reference: np.ndarray, threshold: float) -> Agreement:
    """Agreement of `probs` with `reference` (same shape, N x 1 x H x W)."""
    if probs.shape != reference.shape:
        raise VerificationError(f"output shape {probs.shape} differs from the reference {reference.shape}")
    if not np.all(np.isfinite(probs)):
        raise VerificationError("output contains NaN or inf")
    diff = np.abs(probs.astype(np.float64) - reference.astype(np.float64))
    counts = confusion(probs >= threshold, reference >= threshold)  # the reference plays the ground truth
    return Agreement(
        frames=int(probs.shape[0]),
        max_abs_diff=float(diff.max()),
        mean_abs_diff=float(diff.mean()),
        mask_agreement=counts.pixel_accuracy,
        mask_iou=counts.iou,
    )


def run_session(session, frames: np.ndarray, batch: int = 8) -> np.ndarray:
    """Probabilities of an onnxruntime session on uint8 frames, in batches."""
    name = session.get_inputs()[0].name
    outputs = [session.run(None, {name: frames[i : i + batch]})[0] for i in range(0, len(frames), batch)]
    return np.concatenate(outputs).astype(np.float32, copy=False)


def make_session(path: str | Path, threads: int = 2, providers: list[str] | None = None, spin: bool = True):
    """An onnxruntime session with all graph optimisations and `threads` intra-op threads.

    `spin=False` stops idle worker threads from busy-waiting between runs (see OnnxSegmenter).
    """
    import onnxruntime as ort

    options = ort.SessionOptions()
    if not spin:
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.intra_op_num_threads = int(threads)
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.log_severity_level = 3
    return ort.InferenceSession(str(path), options, providers=providers or ["CPUExecutionProvider"])


def check_onnx(path: str | Path) -> None:
    """onnx.checker with full checks (types and shapes); VerificationError on failure."""
    import onnx

    try:
        onnx.checker.check_model(str(path), full_check=True)
    except (onnx.checker.ValidationError, onnx.shape_inference.InferenceError) as exc:
        raise VerificationError(f"{path}: onnx.checker failed: {exc}") from exc


def verify_against_torch(
    path: str | Path,
    torch_probabilities: Callable[[np.ndarray], np.ndarray],
    frames: np.ndarray,
    threshold: float,
    *,
    max_abs_diff: float = MAX_ABS_DIFF,
    min_agreement: float = MIN_MASK_AGREEMENT,
    threads: int = 2,
) -> Agreement:
    """onnx.checker, then onnxruntime vs `torch_probabilities` on `frames`; raises VerificationError."""
    check_onnx(path)
    session = make_session(path, threads=threads)
    probs = run_session(session, frames)
    reference = torch_probabilities(frames)
    agreement = compare(probs, reference, threshold)
    check_bounds(agreement, str(path), max_abs_diff=max_abs_diff, min_agreement=min_agreement)
    # Dynamic batch: one frame alone must give the same answer as inside a batch.
    single = run_session(session, frames[:1], batch=1)
    if np.abs(single - probs[:1]).max() > max_abs_diff:
        raise VerificationError(f"{path}: batch-1 output differs from the batched output")
    return agreement


def check_bounds(
    agreement: Agreement, source: str, *, max_abs_diff: float, min_agreement: float, model: str = "onnx"
) -> None:
    """VerificationError naming `source` and each bound missed; `model` names the file's kind in it."""
    problems = []
    if not agreement.max_abs_diff <= max_abs_diff:
        problems.append(f"max |p_{model} - p_torch| = {agreement.max_abs_diff:.3g} > {max_abs_diff:g}")
    if not agreement.mask_agreement >= min_agreement:
        problems.append(f"mask agreement {100 * agreement.mask_agreement:.3f} % < {100 * min_agreement:.2f} %")
    if problems:
        raise VerificationError(f"{source}: verification failed on {agreement.frames} frames: " + "; ".join(problems))


def torch_reference(wrapper) -> Callable[[np.ndarray], np.ndarray]:
    """Probabilities of the PyTorch DeployWrapper (eval, no grad) on uint8 NHWC frames."""
    import torch

    def probabilities(frames: np.ndarray) -> np.ndarray:
        outputs = []
        with torch.inference_mode():
            for i in range(0, len(frames), 8):
                outputs.append(wrapper(torch.from_numpy(np.ascontiguousarray(frames[i : i + 8]))).numpy())
        return np.concatenate(outputs).astype(np.float32, copy=False)

    return probabilities
