"""`python -m benchmarks export`: per-frame latency of PyTorch eager vs onnxruntime, and one full SegMinD step.

All candidates are timed in alternating rounds (eager, fp32, INT8, ..., eager, fp32, ...) so that
load from other processes on a shared machine hits every candidate alike; each figure is the
median and 95th percentile over all its rounds. The targets are `TARGETS`, set for the reference
machine: a 2-core CPU, 224 x 224 input, 2 threads.
"""

from __future__ import annotations

import functools
import logging
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.architectures import interleaved
from segmin.common.machine import load_average_1min, usable_cores
from segmin.common.speed_targets import SpeedTarget, verdict_lines, verdicts

TARGETS: tuple[SpeedTarget, ...] = (
    SpeedTarget("ort_fp32_ms", "ort fp32 median", 6.0, "ms"),
    SpeedTarget("ort_fp32_ratio", "ort fp32", 0.35, "x eager"),
    SpeedTarget("full_step_ms", "full step median", 7.0, "ms"),
)
log = logging.getLogger(__name__)

FP32 = "onnxruntime fp32"
INT8 = "onnxruntime INT8 (QDQ)"

# Times a graph for downstream code: (fp32 .onnx, one RGB frame, threads) -> {name: timed call}.
StepCandidates = Callable[[Path, np.ndarray, int], dict[str, Callable[[], object]]]


@dataclass(frozen=True)
class ExportBenchOptions:
    """What `python -m benchmarks export` takes (benchmarks/cli.py has the command-line help)."""

    checkpoint: Path | None = None  # None: random weights (latency does not depend on the weights)
    onnx: Path | None = None  # an exported fp32 file to time instead of exporting the model
    size: int = 224
    threads: int = 2
    runs: int = 200
    int8: bool = True
    compare_exporters: bool = False  # also time the legacy TorchScript exporter's graph
    calib_data: Path | None = None  # frames for INT8 calibration (default: stand-in frames)
    json: Path | None = None  # also write the summary here

    def __post_init__(self) -> None:
        for name, minimum in (("size", 32), ("threads", 1), ("runs", 1)):
            if getattr(self, name) < minimum:
                raise ValueError(f"--{name} {getattr(self, name)}: must be >= {minimum}")


def _field_like_frames(count: int, size: int, seed: int = 0) -> np.ndarray:
    """Deterministic stand-in frames: sky, soil and green row bands with noise (timing only)."""
    rng = np.random.default_rng(seed)
    frames = np.empty((count, size, size, 3), dtype=np.uint8)
    cols = np.arange(size)
    for i in range(count):
        frame = np.zeros((size, size, 3), np.float32)
        frame[: size // 3] = (150, 190, 235)
        frame[size // 3 :] = (120, 95, 70)
        for centre in (size * 0.2 + rng.normal(0, 4), size * 0.8 + rng.normal(0, 4)):
            band = np.abs(cols - centre) < size * 0.12
            frame[size // 5 :, band] = (40, 120 + rng.integers(0, 40), 35)
        frame += rng.normal(0, 12, frame.shape)
        frames[i] = np.clip(frame, 0, 255).astype(np.uint8)
    return frames


def run_benchmark(options: ExportBenchOptions, step_candidates: StepCandidates | None = None) -> dict[str, Any]:
    """Time eager PyTorch against the onnxruntime graphs; print the table, the roofline and the
    targets, and return the summary (also written to `options.json`).

    `step_candidates` adds timers of code downstream of export (the robot-side perception +
    control step): they come from the caller, so this package never imports nav_eval.
    """
    import onnxruntime as ort
    import torch

    torch.set_num_threads(options.threads)
    model, origin = _model(options.checkpoint)
    with tempfile.TemporaryDirectory(prefix="segmin-bench-") as tmp_dir:
        tmp = Path(tmp_dir)
        files, frames = _graphs_and_frames(options, model, tmp)
        frame = frames[:1]
        candidates = _candidates(model, files, frame, options.threads)
        if step_candidates is not None:
            candidates.update(step_candidates(files[FP32], frame[0], options.threads))
        flops = _conv_flops(files[FP32])
        load_before = load_average_1min()
        results, sgemm_peak = _time_with_sgemm_reference(candidates, options, measure_sgemm=flops is not None)
        if "CUDAExecutionProvider" in ort.get_available_providers():
            results.update(_time_fp16_cuda(files[FP32], tmp, frame, options))
    eager_ms = results["pytorch eager"]["median_ms"]
    for entry in results.values():
        entry["ratio_to_eager"] = entry["median_ms"] / eager_ms
    _print_table(options, origin, load_before, results)
    roofline = _roofline(options, flops, results, sgemm_peak)
    targets = _print_targets(results)
    summary = {
        "size": options.size,
        "threads": options.threads,
        "weights": origin,
        "load_average_1min": load_before,
        "results": results,
        "roofline": roofline,
        "targets": targets,
    }
    if options.json is not None:
        from segmin.common.atomic import write_json

        write_json(options.json, summary)
    return summary


def _model(checkpoint: Path | None) -> tuple[Any, str]:
    """The model to export and time, and where its weights come from (for the printout)."""
    import torch

    from segmin.models import build_model
    from segmin.models.checkpoint import load_model

    if checkpoint is not None:
        model, _ = load_model(checkpoint)
        return model, str(checkpoint)
    torch.manual_seed(0)
    return build_model("none").eval(), "random weights (latency does not depend on the weights)"


def _graphs_and_frames(options: ExportBenchOptions, model, tmp: Path) -> tuple[dict[str, Path], np.ndarray]:
    """{candidate name: .onnx file} (the given or a freshly exported fp32 graph, and the variants
    asked for) and the frames: INT8 is calibrated on them, and the first is the timed frame."""
    from segmin.export.onnx import export_graph
    from segmin.export.quantize import quantize_int8
    from segmin.export.verify import load_frames

    size = options.size
    if options.onnx is not None:
        files = {FP32: _given_fp32(options.onnx, options)}
    else:
        files = {FP32: _export_fp32(model, tmp / "fp32.onnx", size)}
    if options.compare_exporters:
        legacy = files["onnxruntime fp32 (legacy exporter)"] = tmp / "legacy.onnx"
        export_graph(model, legacy, input_size=(size, size), exporter="legacy")
    if options.calib_data is not None:
        frames = load_frames(options.calib_data, (size, size), limit=32)
    else:
        frames = _field_like_frames(16, size)
    if options.int8:
        files[INT8] = tmp / "int8.onnx"
        quantize_int8(files[FP32], files[INT8], frames)
    return files, frames


def _export_fp32(model, path: Path, size: int) -> Path:
    """The model exported as the deployed graph (dynamo), with the metadata OnnxSegmenter reads."""
    from segmin.export.onnx import export_graph

    start = time.perf_counter()
    export_graph(model, path, input_size=(size, size), exporter="dynamo")
    _stamp_minimal(path, size)
    print(f"exported {size}x{size} graph (dynamo, opset 18) in {time.perf_counter() - start:.1f} s")
    return path


def _given_fp32(path: Path, options: ExportBenchOptions) -> Path:
    """An exported file to time, refused unless its input is --size x --size."""
    from segmin.export.metadata import KEY_INPUT_SIZE, parse_input_size
    from segmin.export.verify import make_session

    session = make_session(path, threads=options.threads)
    size_hw = parse_input_size(session.get_modelmeta().custom_metadata_map[KEY_INPUT_SIZE])
    if size_hw != (options.size, options.size):
        raise ValueError(f"{path}: model input {size_hw} is not {options.size}x{options.size}; pass --size")
    return Path(path)


def _candidates(model, files: dict[str, Path], frame: np.ndarray, threads: int) -> dict[str, Callable[[], object]]:
    """Eager PyTorch, one onnxruntime session per graph, and fp32 without thread spinning."""
    import torch

    from segmin.export.onnx import DeployWrapper
    from segmin.export.verify import make_session

    wrapper = DeployWrapper(model).eval()
    torch_frame = torch.from_numpy(frame)

    def eager() -> object:
        with torch.inference_mode():
            return wrapper(torch_frame)

    candidates: dict[str, Callable[[], object]] = {"pytorch eager": eager}
    for name, path in files.items():
        session = make_session(path, threads=threads)
        feed = {session.get_inputs()[0].name: frame}
        candidates[name] = functools.partial(session.run, None, feed)
    quiet = make_session(files[FP32], threads=threads, spin=False)
    candidates["onnxruntime fp32, no thread spinning"] = lambda: quiet.run(None, {quiet.get_inputs()[0].name: frame})
    return candidates


def _conv_flops(path: Path) -> int | None:
    """The fp32 graph's convolution FLOPs, or None for a user graph they cannot be counted in."""
    from segmin.export.roofline import conv_flops

    try:
        return conv_flops(path)
    except ValueError as exc:  # time it anyway
        log.warning("no FLOP count for the fp32 graph (%s)", exc)
        return None


def _time_with_sgemm_reference(
    candidates: dict[str, Callable[[], object]], options: ExportBenchOptions, *, measure_sgemm: bool
) -> tuple[dict[str, dict[str, float]], float]:
    """The interleaved timings, and the machine's sgemm rate (best of just before and just after)."""
    from segmin.export.roofline import sgemm_gflops

    sgemm_before = sgemm_gflops(options.threads) if measure_sgemm else 0.0
    results = interleaved(candidates, runs=options.runs)
    sgemm_after = sgemm_gflops(options.threads) if measure_sgemm else 0.0
    return results, max(sgemm_before, sgemm_after)


def _time_fp16_cuda(
    fp32: Path, tmp: Path, frame: np.ndarray, options: ExportBenchOptions
) -> dict[str, dict[str, float]]:
    """The fp16 graph on onnxruntime's CUDA provider (only where one is installed)."""
    from segmin.export.quantize import convert_fp16
    from segmin.export.verify import make_session

    convert_fp16(fp32, tmp / "fp16.onnx")
    session = make_session(tmp / "fp16.onnx", threads=options.threads, providers=["CUDAExecutionProvider"])
    feed = {session.get_inputs()[0].name: frame}
    return interleaved({"onnxruntime fp16 CUDA": lambda: session.run(None, feed)}, runs=options.runs)


def _print_table(
    options: ExportBenchOptions, origin: str, load_before: float | None, results: dict[str, dict[str, float]]
) -> None:
    import onnxruntime as ort
    import torch

    print(
        f"python -m benchmarks export: {options.size}x{options.size}, batch 1, {options.threads} threads, weights: {origin}"
    )
    print(f"onnxruntime {ort.__version__}, torch {torch.__version__}")
    if load_before is not None:
        print(
            f"load average (1 min) before timing: {load_before:.2f} on {usable_cores()} cores; "
            "figures are noisy when it is high"
        )
    print(f"{'model':<56}{'median ms':>10}{'p95 ms':>10}{'min ms':>9}{'x eager':>9}")
    for name, entry in results.items():
        print(
            f"{name:<56}{entry['median_ms']:>10.2f}{entry['p95_ms']:>10.2f}"
            f"{entry['min_ms']:>9.2f}{entry['ratio_to_eager']:>9.2f}"
        )


def _roofline(
    options: ExportBenchOptions, flops: int | None, results: dict[str, dict[str, float]], sgemm_peak: float
) -> dict[str, float] | None:
    """The fp32 graph against this machine's sgemm rate (printed); None without a FLOP count."""
    from segmin.export.roofline import floor_summary

    if flops is None:
        return None
    roofline = floor_summary(flops, results[FP32]["median_ms"], results["pytorch eager"]["median_ms"], sgemm_peak)
    print(
        f"fp32 graph: {roofline['conv_gflop']:.3f} GFLOP of convolutions per frame, run at "
        f"{roofline['achieved_gflops']:.0f} GFLOP/s = {roofline['fraction_of_peak']:.0%} of this machine's "
        f"{options.threads}-thread torch sgemm rate ({roofline['peak_gflops']:.0f} GFLOP/s, best of before/after); "
        f"at that rate a frame would take {roofline['floor_ms']:.2f} ms = {roofline['floor_ratio_to_eager']:.2f}x eager"
    )
    return roofline


def _print_targets(results: dict[str, dict[str, float]]) -> dict[str, bool]:
    """Print the figures against `TARGETS`, the full step's rate and INT8's verdict; returns the verdicts."""
    fp32 = results[FP32]
    figures = {"ort_fp32_ms": fp32["median_ms"], "ort_fp32_ratio": fp32["ratio_to_eager"]}
    step = next((entry for name, entry in results.items() if name.startswith("full step")), None)
    if step is not None:
        figures["full_step_ms"] = step["median_ms"]
    for line in verdict_lines(TARGETS, figures):
        print(line)
    if step is not None:
        rate = 1000.0 / step["median_ms"]
        print(f"full step rate: {rate:.0f} Hz ({rate / 20.0:.1f}x the paper's 20 Hz)")
    if INT8 in results:
        speedup = fp32["median_ms"] / results[INT8]["median_ms"]
        verdict = "faster" if speedup >= 1.05 else "not faster: deploy fp32"
        print(f"INT8 vs fp32: {speedup:.2f}x ({verdict})")
    return verdicts(TARGETS, figures)


def _stamp_minimal(path: Path, size: int) -> None:
    """Metadata OnnxSegmenter needs, for a bench-only graph that has no checkpoint behind it."""
    import onnx

    from segmin.export.onnx import build_metadata, set_metadata

    model = onnx.load(str(path))
    info = {"threshold": 0.5, "family": "bench", "train_data": "none", "backbone_weights": "none"}
    set_metadata(model, build_metadata(info, input_size=(size, size), exporter="dynamo", opset=18))
    onnx.save(model, str(path))
