"""Reduced-precision variants of a verified fp32 export: fp16 (GPU / Jetson) and INT8 static QDQ.

fp16 uses onnxruntime's own converter (`onnxruntime.transformers.float16`, shipped with the
installed onnxruntime, so no extra dependency) with `keep_io_types=True`: the graph still takes
uint8 frames and returns float32 probabilities, so consumers do not change.

INT8 is static QDQ quantisation (`onnxruntime.quantization.quantize_static`) calibrated on real
frames: activations uint8, weights int8, per-tensor. Per-channel is off on purpose: per-channel
static quantisation of MobileNetV3 has a known accuracy problem (onnxruntime issue 11415). On a
2-core x86 CPU the INT8 graph was not faster than fp32 in our measurements (the depthwise convs and
HardSwish/HardSigmoid activations stay float between Q/DQ pairs), so it is built and reported with
its mask IoU and latency, and recommended only when the measured latency is lower.
"""

from __future__ import annotations

import tempfile
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.timing import Latency, interleaved_calls
from segmin.export.verify import Agreement, compare, make_session, run_session

# INT8 is recommended only when it is measurably faster AND its masks stay close to fp32.
INT8_MIN_SPEEDUP = 1.05
INT8_MIN_IOU = 0.95
# fp16 is compared with the fp32 export, not with PyTorch: half precision cannot meet 1e-4.
FP16_MAX_ABS_DIFF = 1e-2
FP16_MIN_AGREEMENT = 0.995


def convert_fp16(src: str | Path, dst: str | Path) -> None:
    """Write an fp16 copy of `src` to `dst`; inputs (uint8) and outputs (float32) keep their types."""
    import onnx
    from onnxruntime.transformers.float16 import convert_float_to_float16

    model = onnx.load(str(src))
    # Resize computes sampling coordinates from float scales/sizes; keep it in float32 so the
    # upsampled output lines up exactly with the fp32 graph.
    half = convert_float_to_float16(model, keep_io_types=True, op_block_list=["Resize"])
    onnx.save(half, str(dst))


class FrameReader:
    """onnxruntime CalibrationDataReader over uint8 frames (one frame per calibration batch)."""

    def __init__(self, frames: np.ndarray, input_name: str) -> None:
        self.frames = frames
        self.input_name = input_name
        self.index = 0

    def get_next(self) -> dict[str, np.ndarray] | None:
        if self.index >= len(self.frames):
            return None
        batch = self.frames[self.index : self.index + 1]
        self.index += 1
        return {self.input_name: batch}

    def rewind(self) -> None:
        self.index = 0


def quantize_int8(src: str | Path, dst: str | Path, frames: np.ndarray) -> None:
    """Static QDQ INT8 quantisation of `src`, calibrated on `frames` (uint8 N x H x W x 3)."""
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    if len(frames) == 0:
        raise ValueError("INT8 calibration needs at least one frame")

    class _Reader(FrameReader, CalibrationDataReader):
        pass

    with tempfile.TemporaryDirectory(prefix="segmin-int8-") as tmp:
        prepared = Path(tmp) / "prepared.onnx"
        quant_pre_process(str(src), str(prepared), skip_symbolic_shape=False)
        name = make_session(prepared, threads=1).get_inputs()[0].name
        quantize_static(
            str(prepared),
            str(dst),
            _Reader(frames, name),
            quant_format=QuantFormat.QDQ,
            per_channel=False,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
        )


def compare_with_fp32(path: str | Path, fp32_probs: np.ndarray, frames: np.ndarray, threshold: float) -> Agreement:
    """Agreement of a reduced-precision file with the fp32 export's probabilities."""
    return compare(run_session(make_session(path), frames), fp32_probs, threshold)


def interleaved_latency(
    paths: dict[str, Path], frame: np.ndarray, threads: int = 2, runs: int = 50, rounds: int = 3
) -> dict[str, Latency]:
    """Latency of several files measured in alternating rounds, so load from others hits all alike."""
    sessions = {name: make_session(path, threads=threads) for name, path in paths.items()}
    calls = {
        name: partial(session.run, None, {session.get_inputs()[0].name: frame}) for name, session in sessions.items()
    }
    return interleaved_calls(calls, runs=runs, rounds=rounds)


def int8_report(agreement: Agreement, latency: dict[str, Latency], calibration_frames: int) -> dict[str, Any]:
    """An INT8 file's report entry (ONNX or LiteRT): its agreement with fp32, both latencies and
    the recommendation."""
    speedup = latency["fp32"].median_ms / latency["int8"].median_ms
    recommended = speedup >= INT8_MIN_SPEEDUP and agreement.mask_iou >= INT8_MIN_IOU
    reason = (
        f"calibrated on {calibration_frames} frames, "
        f"INT8 median {latency['int8'].median_ms:.2f} ms vs fp32 {latency['fp32'].median_ms:.2f} ms "
        f"({speedup:.2f}x), mask IoU vs fp32 {agreement.mask_iou:.4f}: "
        + ("recommended" if recommended else "not recommended, deploy the fp32 file")
    )
    return {
        "vs_fp32": agreement.as_dict(),
        "latency_ms": {name: lat.as_dict() for name, lat in latency.items()},
        "calibration_frames": calibration_frames,
        "speedup_vs_fp32": speedup,
        "recommended": recommended,
        "recommendation": reason,
    }
