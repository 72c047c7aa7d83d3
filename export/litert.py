"""A SegmentationNet as a verified LiteRT (.tflite) file, fp32 and full-integer INT8.

Converter: litert-torch (`litert_torch.convert`, PyPI `litert-torch`, Google's maintained
PyTorch -> LiteRT converter, the successor of ai-edge-torch). It lowers the `torch.export`
program to the LiteRT flatbuffer itself, so no TensorFlow is installed, and it turns PyTorch's
NCHW graph into LiteRT's NHWC one without leftover transposes. It converts the same
`DeployWrapper` the ONNX export does, so the file has the same contract: uint8 RGB frames
1 x H x W x 3 in (the batch is fixed at 1: the robot segments one frame at a time), /255 and
ImageNet normalisation and the sigmoid inside, vegetation probability 1 x 1 x H x W out.

INT8: ai-edge-quantizer's full-integer static recipe (`static_wi8_ai8`: int8 weights per channel,
int8 activations) applied to the verified fp32 file, calibrated on real frames, as the ONNX INT8
variant is made from the verified ONNX file, with one change: HARD_SWISH stays float. XNNPACK
(ai-edge-litert 2.3) has no int8 hard-swish, so with it quantised each of MobileNetV3's 15
hard-swish ops ran in LiteRT's own int8 kernel between 16 XNNPACK partitions, and the INT8 file
was 1.5x slower than fp32; kept float (a DEQUANTIZE / QUANTIZE pair around each, both XNNPACK
ops), the whole graph but the input CAST is one XNNPACK partition and INT8 is faster than fp32
(docs/results/history/litert.md). Its output is int8 (probability = scale x (q - zero point),
exact to 1/256); `export.litert_file.Runner` gives float32 probabilities either way.
"""

from __future__ import annotations

import logging
import os
import warnings
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from segmin.common.atomic import atomic_path
from segmin.common.timing import Latency, interleaved_calls
from segmin.export import litert_file
from segmin.export import metadata as md
from segmin.export.onnx import DeployWrapper
from segmin.export.quantize import int8_report
from segmin.export.verify import Agreement, VerificationError, check_bounds, compare, torch_reference

log = logging.getLogger(__name__)

SIGNATURE = "serving_default"  # the converted model's one signature
# Ops the INT8 file keeps float: XNNPACK has no int8 kernel for them (see the module docstring).
INT8_FLOAT_OPS = ("HARD_SWISH",)
_PROGRESS_ENV = "LITERT_TORCH_SHOW_PROGRESS"


def converter_name() -> str:
    """What goes into the metadata's `exporter` key: the converter and its version."""
    from importlib.metadata import version

    return f"litert-torch {version('litert-torch')}"


def convert_graph(model: nn.Module, path: str | Path, input_size: tuple[int, int]) -> None:
    """Write the wrapped model as a fp32 LiteRT flatbuffer (no segmin metadata yet) to `path`."""
    import litert_torch

    height, width = (int(v) for v in input_size)
    wrapper = DeployWrapper(model).eval()
    example = torch.zeros(1, height, width, 3, dtype=torch.uint8)
    # litert-torch prints its progress to stdout (through an environment variable it reads): off
    # here, so that stdout stays segmin's result lines, and the caller's setting put back after.
    previous = os.environ.get(_PROGRESS_ENV)
    os.environ[_PROGRESS_ENV] = "n"
    try:
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            litert_torch.convert(wrapper, (example,)).export(str(path))
    finally:
        if previous is None:
            del os.environ[_PROGRESS_ENV]
        else:
            os.environ[_PROGRESS_ENV] = previous


def int8_recipe(float_ops: tuple[str, ...] = INT8_FLOAT_OPS) -> list[dict[str, Any]]:
    """ai-edge-quantizer's `static_wi8_ai8` recipe with `float_ops` left unquantised (a recipe is a
    list of rules, the last matching one wins)."""
    from ai_edge_quantizer import recipe

    keep = [{"regex": ".*", "operation": op, "algorithm_key": "no_quantize", "op_config": {}} for op in float_ops]
    return [*recipe.static_wi8_ai8(), *keep]


def quantize_int8(
    src: str | Path, dst: str | Path, frames: np.ndarray, float_ops: tuple[str, ...] = INT8_FLOAT_OPS
) -> None:
    """INT8 copy of the fp32 file `src` at `dst` (int8 weights and activations, `float_ops` float),
    calibrated on uint8 N x H x W x 3 frames."""
    from ai_edge_quantizer import quantizer

    if len(frames) == 0:
        raise ValueError("INT8 calibration needs at least one frame")
    interpreter = litert_file.make_interpreter(src, threads=1)
    (input_name,) = interpreter.get_signature_list()[SIGNATURE]["inputs"]
    engine = quantizer.Quantizer(str(src), int8_recipe(float_ops))
    with warnings.catch_warnings():  # calibration keeps every tensor on purpose; LiteRT warns that it does
        warnings.filterwarnings("ignore", message=".*experimental_preserve_all_tensors")
        calibration = engine.calibrate({SIGNATURE: [{input_name: frames[i : i + 1]} for i in range(len(frames))]})
    Path(dst).write_bytes(bytes(engine.quantize(calibration, enable_progress_report=False).quantized_model))


def run_file(path: str | Path, frames: np.ndarray, threads: int = 2) -> np.ndarray:
    """Probabilities of a .tflite file on uint8 frames (N x 1 x H x W float32)."""
    return litert_file.run_frames(litert_file.Runner(litert_file.make_interpreter(path, threads)), frames)


def check_io(path: str | Path, input_size: tuple[int, int]) -> None:
    """The converted file must take uint8 1 x H x W x 3 and give 1 x 1 x H x W."""
    interpreter = litert_file.make_interpreter(path, threads=1)
    inputs, outputs = interpreter.get_input_details(), interpreter.get_output_details()
    height, width = (int(v) for v in input_size)
    if len(inputs) != 1 or len(outputs) != 1:
        raise ValueError(f"{path}: expected one input and one output, got {len(inputs)} and {len(outputs)}")
    if inputs[0]["dtype"] != np.uint8 or list(inputs[0]["shape"]) != [1, height, width, 3]:
        raise ValueError(
            f"{path}: input is {inputs[0]['dtype'].__name__} {list(inputs[0]['shape'])}, not uint8 "
            f"[1, {height}, {width}, 3]"
        )
    if list(outputs[0]["shape"]) != [1, 1, height, width]:
        raise ValueError(f"{path}: output shape {list(outputs[0]['shape'])} is not [1, 1, {height}, {width}]")


def export_litert(
    options: Any,
    int8_path: Path,
    model: nn.Module,
    meta: dict[str, str],
    verify_set: np.ndarray,
    calib_set: np.ndarray | None,
    threshold: float,
    input_size: tuple[int, int],
) -> dict[str, Any]:
    """fp32 file verified against PyTorch (and an INT8 one compared with it when `calib_set` is
    given, written to `int8_path`), each written atomically; returns their report entries ("fp32", "int8")."""
    out = Path(options.out)
    report: dict[str, Any] = {}
    with atomic_path(out) as tmp:
        convert_graph(model, tmp, input_size)
        check_io(tmp, input_size)
        litert_file.stamp(tmp, meta)
        probs = run_file(tmp, verify_set, options.threads)
        agreement = compare(probs, torch_reference(DeployWrapper(model).eval())(verify_set), threshold)
        try:
            check_bounds(
                agreement,
                str(out),
                max_abs_diff=options.max_abs_diff,
                min_agreement=options.min_agreement,
                model="tflite",
            )
        except VerificationError as exc:
            kept = " (the existing file was left unchanged)" if out.exists() else ""
            raise VerificationError(f"{out}: export failed verification, no file written{kept}: {exc}") from exc
        litert_file.stamp(tmp, {"verification": agreement.summary()})
    report["fp32"] = {"path": str(out), "verification_vs_torch": agreement.as_dict()}
    log.info("wrote %s (verified: %s)", out, agreement.summary())
    if calib_set is not None:
        with atomic_path(int8_path) as tmp:
            quantize_int8(out, tmp, calib_set)
            int8_agreement: Agreement = compare(run_file(tmp, verify_set, options.threads), probs, threshold)
            litert_file.stamp(
                tmp,
                {
                    **meta,
                    md.KEY_PRECISION: "int8",
                    md.KEY_OUTPUT: "vegetation probability, 1 x 1 x H x W, int8 (probability = scale x (q - zero "
                    "point), the output tensor's quantisation; sigmoid applied)",
                    "verification": "vs fp32: " + int8_agreement.summary(),
                },
            )
            latency = interleaved_latency({"fp32": out, "int8": tmp}, verify_set[:1], threads=options.threads)
        report["int8"] = {"path": str(int8_path), **int8_report(int8_agreement, latency, len(calib_set))}
    return report


def interleaved_latency(
    paths: dict[str, Path], frame: np.ndarray, threads: int = 2, runs: int = 30
) -> dict[str, Latency]:
    """Latency of several .tflite files on one frame, timed in alternating rounds."""
    runners = {name: litert_file.Runner(litert_file.make_interpreter(path, threads)) for name, path in paths.items()}
    return interleaved_calls({name: partial(runner, frame) for name, runner in runners.items()}, runs=runs)
