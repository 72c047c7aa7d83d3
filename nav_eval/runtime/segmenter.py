"""Segmenters the navigator loads: camera RGB in, vegetation mask out.

`OnnxSegmenter` runs a file written by `segmin export` with onnxruntime only (no torch, no
training code: this module is what runs on the robot computer); `LiteRtSegmenter` runs one
written by `segmin export --format tflite` with the LiteRT interpreter (`ai-edge-litert`, the
`litert` extra) and its XNNPACK CPU delegate. The file's metadata says the
input size and threshold; the graph itself does the /255 and ImageNet normalisation, so the only
preprocessing here is a resize to the model size (`data.model_input.resize_to_input`, shared with
export verification: INTER_AREA when shrinking, INTER_LINEAR when enlarging). The mask is computed at the model size and resized back to the frame size with
nearest neighbour, so it stays boolean and its edges do not move by more than one model pixel;
`probabilities` is resized back bilinearly.

Both are `nav_eval.runtime.protocols.Segmenter`s. The simulator's exact-mask oracle
is not (it needs the whole rendered frame): it lives in `nav_eval.sim.oracle`.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segmin.data.model_input import resize_to_input
from segmin.export import metadata as md

from .shipped_models import SHIPPED_NAMES, resolve_model, shipped_model

log = logging.getLogger(__name__)

# Whether onnxruntime's idle worker threads busy-wait for the next run (see OnnxSegmenter). Off:
# a robot's camera, IMU and motor drivers share its cores, and spinning threads take them (two
# spinning sessions in one process slowed each other 1.2-2.2x; medians under load were 2-8x
# slower than without): spin only with a core to spare.
SPIN_DEFAULT = False
# A shipped model's fastest file (runtime_model_file): full-integer INT8 LiteRT, hard-swish float.
FAST_SUFFIX = ".int8.tflite"


def check_rgb(rgb: np.ndarray) -> np.ndarray:
    """The frame as a C-contiguous uint8 H x W x 3 array; ValueError naming the problem."""
    if not isinstance(rgb, np.ndarray):
        raise ValueError(f"frame must be a numpy array (uint8 H x W x 3 RGB), got {type(rgb).__name__}")
    if rgb.dtype != np.uint8:
        raise ValueError(f"frame dtype is {rgb.dtype}, expected uint8 RGB (0..255)")
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"frame shape is {rgb.shape}, expected H x W x 3 (RGB, 3 channels)")
    if rgb.shape[0] < 1 or rgb.shape[1] < 1:
        raise ValueError(f"frame shape is {rgb.shape}: empty image")
    return np.ascontiguousarray(rgb)


@dataclass(frozen=True)
class PreparedFrame:
    """A checked frame resized to the model input: `batch` is uint8 1 x h x w x 3."""

    batch: np.ndarray
    frame_shape: tuple[int, int]  # (H, W) of the original frame, for the mask


class _ModelFileSegmenter:
    """What both segmenters share: the metadata's input size and threshold, the resize to the
    model input and the mask / probabilities back at the frame size. A subclass runs the model."""

    path: os.PathLike
    input_size: tuple[int, int]
    threshold: float

    def _read_metadata(self, metadata: dict[str, str], threshold: float | None, file_format: str) -> None:
        self.metadata = metadata
        md.check_metadata(self.metadata, str(self.path), file_format)
        self.input_size = md.parse_input_size(self.metadata[md.KEY_INPUT_SIZE])
        self.threshold = float(self.metadata[md.KEY_THRESHOLD]) if threshold is None else float(threshold)
        if not 0.0 < self.threshold < 1.0:
            raise ValueError(f"threshold must be in (0, 1), got {self.threshold!r}")

    def prepare(self, rgb: np.ndarray) -> PreparedFrame:
        """Check and resize a frame for the model (the part of `segment` before the runtime).

        A caller that overlaps segmentation with other work runs this on its own thread and
        `segment_prepared` on a helper: the helper then releases the GIL at its first step.
        """
        rgb = check_rgb(rgb)
        frame_shape = (int(rgb.shape[0]), int(rgb.shape[1]))
        return PreparedFrame(resize_to_input(rgb, self.input_size)[None], frame_shape)

    def _model_probabilities(self, prepared: PreparedFrame) -> np.ndarray:
        """Probabilities at the model input size (float32 h x w)."""
        raise NotImplementedError

    def probabilities(self, rgb: np.ndarray) -> np.ndarray:
        """float32 H x W vegetation probability at the frame size (bilinear resize back)."""
        import cv2

        prepared = self.prepare(rgb)
        probs = self._model_probabilities(prepared)
        height, width = prepared.frame_shape
        if probs.shape != (height, width):
            probs = cv2.resize(probs, (width, height), interpolation=cv2.INTER_LINEAR)
        return np.clip(probs, 0.0, 1.0).astype(np.float32, copy=False)

    def segment(self, rgb: np.ndarray) -> np.ndarray:
        """bool H x W vegetation mask at the frame size (thresholded at the model size, nearest resize)."""
        return self.segment_prepared(self.prepare(rgb))

    def segment_prepared(self, prepared: PreparedFrame) -> np.ndarray:
        """The mask of a frame from `prepare` (the model, threshold, resize back)."""
        import cv2

        mask: np.ndarray = (self._model_probabilities(prepared) >= self.threshold).astype(np.uint8)
        height, width = prepared.frame_shape
        if mask.shape != (height, width):
            mask = cv2.resize(mask, (width, height), interpolation=cv2.INTER_NEAREST)
        return mask.astype(bool)

    def __repr__(self) -> str:
        height, width = self.input_size
        return f"{type(self).__name__}({str(self.path)!r}, input {height}x{width}, threshold {self.threshold:g})"


class OnnxSegmenter(_ModelFileSegmenter):
    """A `segmin export` ONNX file run by onnxruntime on the CPU (or a given provider list).

    `path`: the file, or a shipped model's name ("vineyards", "trees"; see `shipped_models`).

    `threads`: onnxruntime intra-op threads (the paper's robot computer budget: 2).
    `threshold`: probability above which a pixel is vegetation; None = the file's metadata value.
    `spin`: let onnxruntime's worker threads busy-wait between runs (lowest latency on an
    otherwise idle CPU); False frees the cores for the rest of the control loop between frames.
    """

    name = "onnx"

    def __init__(
        self,
        path: str | os.PathLike,
        threads: int = 2,
        threshold: float | None = None,
        providers: list[str] | None = None,
        spin: bool = SPIN_DEFAULT,
    ) -> None:
        self.path = resolve_model(path, what="model")
        if int(threads) < 1:
            raise ValueError(f"threads must be >= 1, got {threads!r}")
        from segmin.export.verify import make_session  # torch-free: the export checks use the same session

        try:
            self.session = make_session(self.path, threads=int(threads), providers=providers, spin=spin)
        except Exception as exc:  # onnxruntime raises its own types for unparsable files
            raise ValueError(f"{self.path}: not a loadable ONNX model ({str(exc).splitlines()[0][:300]})") from exc

        self._read_metadata(dict(self.session.get_modelmeta().custom_metadata_map), threshold, md.FORMAT)
        self._check_graph()
        self._input_name = self.session.get_inputs()[0].name

    def _check_graph(self) -> None:
        """The graph's input/output must be what the metadata promises."""
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        if len(inputs) != 1 or len(outputs) != 1:
            raise ValueError(f"{self.path}: expected one input and one output, got {len(inputs)} and {len(outputs)}")
        graph_input = inputs[0]
        if graph_input.type != "tensor(uint8)":
            raise ValueError(
                f"{self.path}: model input {graph_input.name!r} is {graph_input.type}, metadata says uint8"
            )
        shape = list(graph_input.shape)
        height, width = self.input_size
        if len(shape) != 4 or shape[1:] != [height, width, 3]:
            raise ValueError(
                f"{self.path}: model input shape {shape} does not match metadata "
                f"{md.KEY_INPUT_SIZE}={height},{width} (expected [N, {height}, {width}, 3])"
            )
        if outputs[0].type != "tensor(float)":
            raise ValueError(f"{self.path}: model output is {outputs[0].type}, expected float32 probabilities")

    def _model_probabilities(self, prepared: PreparedFrame) -> np.ndarray:
        """Probabilities at the model input size (float32 h x w)."""
        return self.session.run(None, {self._input_name: prepared.batch})[0][0, 0]


class LiteRtSegmenter(_ModelFileSegmenter):
    """A `segmin export --format tflite` file run by the LiteRT interpreter with XNNPACK on the CPU.

    `path`: the file, or a shipped model's name, resolved to `<name>.tflite` in the registry folder
    (`shipped_models.models_dir()`): shipped models come as ONNX, so a LiteRT file of one is
    exported once (`segmin export --format tflite --checkpoint vineyards ...`) and put there.
    `threads`: XNNPACK threads (the paper's robot computer budget: 2). `threshold`: as for
    `OnnxSegmenter`. Needs `ai-edge-litert` (`pip install segmin[litert]`).
    """

    name = "litert"

    def __init__(self, path: str | os.PathLike, threads: int = 2, threshold: float | None = None) -> None:
        from segmin.export import litert_file

        self.path = resolve_model(path, what="model", suffix=".tflite")
        if int(threads) < 1:
            raise ValueError(f"threads must be >= 1, got {threads!r}")
        # The metadata first: a file that is not segmin's fails on it before the interpreter loads it.
        self._read_metadata(litert_file.read_metadata(self.path), threshold, md.FORMAT_LITERT)
        self._runner = litert_file.Runner(litert_file.make_interpreter(self.path, threads=int(threads)))
        shape = [int(v) for v in self._runner.input["shape"]]
        height, width = self.input_size
        if self._runner.input["dtype"] != np.uint8 or shape != [1, height, width, 3]:
            raise ValueError(
                f"{self.path}: model input is {np.dtype(self._runner.input['dtype']).name} {shape}, metadata says "
                f"uint8 [1, {height}, {width}, 3]"
            )

    def _model_probabilities(self, prepared: PreparedFrame) -> np.ndarray:
        """Probabilities at the model input size (float32 h x w)."""
        return self._runner(prepared.batch)[0, 0]


def litert_installed() -> bool:
    """Whether the LiteRT interpreter (`pip install segmin[litert]`) can be imported."""
    import importlib.util

    return importlib.util.find_spec("ai_edge_litert") is not None


def runtime_model_file(model: str | os.PathLike, what: str = "--model") -> Path:
    """The file `load_segmenter` runs for a model argument: a file as given; a shipped name's
    INT8 LiteRT file where LiteRT is installed, else its ONNX file.

    The INT8 LiteRT file with XNNPACK is the fastest configuration measured on 2 cores, idle and
    beside busy processes (`segmin bench model-speed`: 0.52-0.72x the paper's model's frame time,
    the ONNX file 0.85-1.0x), with the masks and the steering of the fp32 model within the
    tolerances in the models guide."""
    text = os.fspath(model)
    if text.lower().endswith(".tflite"):
        return resolve_model(model, what=what, suffix=".tflite")
    if text in SHIPPED_NAMES and not Path(text).exists():
        fast = shipped_model(text).onnx.with_suffix(FAST_SUFFIX)
        if fast.is_file() and litert_installed():
            return fast
        log.info(
            "%s %s: running its ONNX file (pip install segmin[litert] runs the faster INT8 LiteRT file)", what, text
        )
    return resolve_model(model, what=what)


def load_segmenter(
    model: str | os.PathLike, threads: int = 2, what: str = "--model", spin: bool = SPIN_DEFAULT
) -> OnnxSegmenter | LiteRtSegmenter:
    """The segmenter for a model argument (`what` names it in errors): the file `runtime_model_file`
    picks, a .tflite file in `LiteRtSegmenter`, an .onnx file in `OnnxSegmenter` (`spin`: its
    threads' busy-wait)."""
    path = runtime_model_file(model, what)
    if path.suffix.lower() == ".tflite":
        return LiteRtSegmenter(path, threads=threads)
    return OnnxSegmenter(path, threads=threads, spin=spin)
