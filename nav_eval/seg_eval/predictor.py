"""The model `segmin eval-seg` scores: an exported ONNX or LiteRT file (what the robot runs) or a training checkpoint.

Preprocessing is the deployed one for both kinds of model: the photo is resized to the model
input with `data.model_input.resize_to_input` (INTER_AREA when shrinking, INTER_LINEAR when
enlarging, as `nav_eval.runtime.segmenter.OnnxSegmenter` does), the uint8 RGB batch goes through
the ONNX graph, the LiteRT file (`LiteRtSegmenter`) or through `export.onnx.DeployWrapper` (which does /255 and ImageNet normalisation
exactly like the graph), and the probability is resized back bilinearly to the photo size and
thresholded there (`>= threshold`, as the segmenter does), so metrics are computed at the
ground-truth resolution.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segmin.data.model_input import check_input_side, resize_to_input
from segmin.export import metadata as md

ONNX_SUFFIXES = (".onnx",)
LITERT_SUFFIXES = (".tflite",)
CHECKPOINT_SUFFIXES = (".pt", ".pth", ".ckpt")


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

        batch = resize_to_input(np.ascontiguousarray(rgb), self.input_size)[None]
        probs: np.ndarray = np.asarray(self.model_probabilities(batch), np.float32).reshape(self.input_size)
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
    if size is not None:
        check_input_side(int(size), "--size")
    suffix = path.suffix.lower()
    if suffix in ONNX_SUFFIXES:
        predictor = _onnx_predictor(path, threads, size)
    elif suffix in LITERT_SUFFIXES:
        predictor = _litert_predictor(path, threads, size)
    elif suffix in CHECKPOINT_SUFFIXES:
        predictor = _checkpoint_predictor(path, size)
    else:
        raise ValueError(
            f"{path}: unknown model type {suffix or '(no suffix)'!r}; expected an exported .onnx or .tflite "
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


def _litert_predictor(path: Path, threads: int, size: int | None) -> Predictor:
    """A `segmin export --format tflite` file, run as the robot runs it (`LiteRtSegmenter`)."""
    from segmin.nav_eval.runtime.segmenter import LiteRtSegmenter

    segmenter = LiteRtSegmenter(path, threads=threads)
    if size is not None and (int(size), int(size)) != segmenter.input_size:
        height, width = segmenter.input_size
        raise ValueError(f"--size {size}: {path} has a fixed {height}x{width} input (--size applies to checkpoints)")

    def probabilities(batch: np.ndarray) -> np.ndarray:
        return segmenter.probabilities(batch[0])  # already at the input size: no resize

    return Predictor(path, "litert", segmenter.input_size, segmenter.threshold, probabilities)


def _checkpoint_predictor(path: Path, size: int | None) -> Predictor:
    from segmin.export.onnx import DeployWrapper
    from segmin.export.verify import torch_reference
    from segmin.models.checkpoint import load_model  # torch.load(weights_only=True)

    try:
        model, info = load_model(path)
    except ValueError as exc:  # torch's unpickler explains itself over several lines: keep the first
        first = str(exc).splitlines()[0].rstrip()
        raise ValueError(first + (" ...)" if first.count("(") > first.count(")") else "")) from exc
    if size is not None:
        input_size = (int(size), int(size))
    else:  # load_model checked it is [height, width]
        height, width = (int(v) for v in info["input_size"])
        input_size = (height, width)
    reference = torch_reference(DeployWrapper(model).eval())

    def probabilities(batch: np.ndarray) -> np.ndarray:
        return reference(batch)[0, 0]

    return Predictor(path, "checkpoint", input_size, float(info.get("threshold", 0.5)), probabilities)
