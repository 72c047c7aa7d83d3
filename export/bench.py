"""`segmin bench export`: per-frame latency of PyTorch eager vs onnxruntime, and one full SegMinD step.

All candidates are timed in alternating rounds (eager, fp32, INT8, ..., eager, fp32, ...) so that
load from other processes on a shared machine hits every candidate alike; each figure is the
median and 95th percentile over all its rounds. Targets (2-core CPU, 224 x 224, 2 threads):
onnxruntime fp32 median <= 6 ms and <= 0.35x eager; OnnxSegmenter + Navigator.step <= 7 ms.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from segmin.common.timing import time_calls

TARGET_ORT_MS = 6.0
TARGET_RATIO = 0.35
TARGET_STEP_MS = 7.0


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


def interleaved(candidates: dict[str, Callable[[], object]], runs: int, rounds: int = 8) -> dict[str, dict[str, float]]:
    """Median / p95 milliseconds of each callable, measured in alternating rounds."""
    samples: dict[str, list[float]] = {name: [] for name in candidates}
    per_round = max(1, runs // rounds)
    for _ in range(rounds):
        for name, call in candidates.items():
            samples[name].extend(time_calls(call, runs=per_round, warmup=min(3, per_round)) * 1e3)
    return {
        name: {
            "median_ms": float(np.median(s)),
            "p95_ms": float(np.percentile(s, 95)),
            "min_ms": float(np.min(s)),
            "runs": len(s),
        }
        for name, s in samples.items()
    }


def run_benchmark(
    *,
    checkpoint: Path | None = None,
    onnx_path: Path | None = None,
    size: int = 224,
    threads: int = 2,
    runs: int = 200,
    int8: bool = True,
    compare_exporters: bool = False,
    calib_data: Path | None = None,
    json_path: Path | None = None,
    step_candidates: Callable[[Path, np.ndarray, int], dict[str, Callable[[], object]]] | None = None,
) -> dict:
    import onnxruntime as ort
    import torch

    from segmin.export.metadata import KEY_INPUT_SIZE, parse_input_size
    from segmin.export.onnx import DeployWrapper, export_graph
    from segmin.export.quantize import quantize_int8
    from segmin.export.roofline import conv_flops, floor_summary, sgemm_gflops
    from segmin.export.verify import load_frames, make_session
    from segmin.models import build_model
    from segmin.models.checkpoint import load_model

    torch.set_num_threads(threads)
    if checkpoint is not None:
        model, _ = load_model(checkpoint)
        origin = str(checkpoint)
    else:
        torch.manual_seed(0)
        model = build_model("none").eval()
        origin = "random weights (latency does not depend on the weights)"
    wrapper = DeployWrapper(model).eval()

    with tempfile.TemporaryDirectory(prefix="segmin-bench-") as tmp_dir:
        tmp = Path(tmp_dir)
        files: dict[str, Path] = {}
        if onnx_path is not None:
            session = make_session(onnx_path, threads=threads)
            size_hw = parse_input_size(session.get_modelmeta().custom_metadata_map[KEY_INPUT_SIZE])
            if size_hw != (size, size):
                raise ValueError(f"{onnx_path}: model input {size_hw} is not {size}x{size}; pass --size")
            files["onnxruntime fp32"] = Path(onnx_path)
        else:
            start = time.perf_counter()
            files["onnxruntime fp32"] = tmp / "fp32.onnx"
            export_graph(model, files["onnxruntime fp32"], input_size=(size, size), exporter="dynamo")
            _stamp_minimal(files["onnxruntime fp32"], size)
            print(f"exported {size}x{size} graph (dynamo, opset 18) in {time.perf_counter() - start:.1f} s")
        if compare_exporters:
            files["onnxruntime fp32 (legacy exporter)"] = tmp / "legacy.onnx"
            export_graph(model, files["onnxruntime fp32 (legacy exporter)"], input_size=(size, size), exporter="legacy")
        frames = (
            load_frames(calib_data, (size, size), limit=32) if calib_data is not None else _field_like_frames(16, size)
        )
        if int8:
            files["onnxruntime INT8 (QDQ)"] = tmp / "int8.onnx"
            quantize_int8(files["onnxruntime fp32"], files["onnxruntime INT8 (QDQ)"], frames)

        frame = frames[:1]
        torch_frame = torch.from_numpy(frame)
        candidates: dict[str, Callable[[], object]] = {}

        def eager() -> object:
            with torch.inference_mode():
                return wrapper(torch_frame)

        candidates["pytorch eager"] = eager
        for name, path in files.items():
            session = make_session(path, threads=threads)
            feed = {session.get_inputs()[0].name: frame}
            candidates[name] = lambda s=session, f=feed: s.run(None, f)
        quiet = make_session(files["onnxruntime fp32"], threads=threads, spin=False)
        candidates["onnxruntime fp32, no thread spinning"] = lambda: quiet.run(
            None, {quiet.get_inputs()[0].name: frame}
        )

        if step_candidates is not None:
            # Timers of code downstream of export (the robot-side perception + control step)
            # come from the caller, so this package never imports nav_eval.
            candidates.update(step_candidates(files["onnxruntime fp32"], frame[0], threads))
        try:
            flops: int | None = conv_flops(files["onnxruntime fp32"])
        except ValueError as exc:  # a user graph we cannot count: time it anyway
            print(f"no FLOP count for the fp32 graph ({exc})")
            flops = None
        load_before = _load_average()
        sgemm_before = sgemm_gflops(threads) if flops is not None else 0.0
        results = interleaved(candidates, runs=runs)
        sgemm_after = sgemm_gflops(threads) if flops is not None else 0.0

        cuda = {}
        if "CUDAExecutionProvider" in ort.get_available_providers():
            from segmin.export.quantize import convert_fp16

            convert_fp16(files["onnxruntime fp32"], tmp / "fp16.onnx")
            session = make_session(tmp / "fp16.onnx", threads=threads, providers=["CUDAExecutionProvider"])
            feed = {session.get_inputs()[0].name: frame}
            cuda = interleaved({"onnxruntime fp16 CUDA": lambda: session.run(None, feed)}, runs=runs)
            results.update(cuda)

    eager_ms = results["pytorch eager"]["median_ms"]
    for entry in results.values():
        entry["ratio_to_eager"] = entry["median_ms"] / eager_ms
    print(f"segmin bench export: {size}x{size}, batch 1, {threads} threads, weights: {origin}")
    print(f"onnxruntime {ort.__version__}, torch {torch.__version__}")
    load = load_before
    if load is not None:
        print(
            f"load average (1 min) before timing: {load:.2f} on {_cpu_count()} cores; figures are noisy when it is high"
        )
    print(f"{'model':<56}{'median ms':>10}{'p95 ms':>10}{'min ms':>9}{'x eager':>9}")
    for name, entry in results.items():
        print(
            f"{name:<56}{entry['median_ms']:>10.2f}{entry['p95_ms']:>10.2f}"
            f"{entry['min_ms']:>9.2f}{entry['ratio_to_eager']:>9.2f}"
        )
    fp32 = results["onnxruntime fp32"]
    roofline = None
    if flops is not None:
        roofline = floor_summary(flops, fp32["median_ms"], eager_ms, max(sgemm_before, sgemm_after))
        print(
            f"fp32 graph: {roofline['conv_gflop']:.3f} GFLOP of convolutions per frame, run at "
            f"{roofline['achieved_gflops']:.0f} GFLOP/s = {roofline['fraction_of_peak']:.0%} of this machine's "
            f"{threads}-thread torch sgemm rate ({roofline['peak_gflops']:.0f} GFLOP/s, best of before/after); "
            f"at that rate a frame would take {roofline['floor_ms']:.2f} ms = {roofline['floor_ratio_to_eager']:.2f}x eager"
        )
    checks = {
        f"ort fp32 median <= {TARGET_ORT_MS} ms": fp32["median_ms"] <= TARGET_ORT_MS,
        f"ort fp32 <= {TARGET_RATIO}x eager": fp32["ratio_to_eager"] <= TARGET_RATIO,
    }
    step = next((entry for name, entry in results.items() if name.startswith("full step")), None)
    if step is not None:
        checks[f"full step median <= {TARGET_STEP_MS} ms"] = step["median_ms"] <= TARGET_STEP_MS
    for label, ok in checks.items():
        print(f"target {label}: {'met' if ok else 'NOT met'}")
    if step is not None:
        rate = 1000.0 / step["median_ms"]
        print(f"full step rate: {rate:.0f} Hz ({rate / 20.0:.1f}x the paper's 20 Hz)")
    if "onnxruntime INT8 (QDQ)" in results:
        speedup = fp32["median_ms"] / results["onnxruntime INT8 (QDQ)"]["median_ms"]
        verdict = "faster" if speedup >= 1.05 else "not faster: deploy fp32"
        print(f"INT8 vs fp32: {speedup:.2f}x ({verdict})")
    summary = {
        "size": size,
        "threads": threads,
        "weights": origin,
        "load_average_1min": load_before,
        "results": results,
        "roofline": roofline,
        "targets": checks,
    }
    if json_path is not None:
        from segmin.common.atomic import write_json

        write_json(json_path, summary)
    return summary


def _stamp_minimal(path: Path, size: int) -> None:
    """Metadata OnnxSegmenter needs, for a bench-only graph that has no checkpoint behind it."""
    import onnx

    from segmin.export.onnx import build_metadata, set_metadata

    model = onnx.load(str(path))
    info = {"threshold": 0.5, "family": "bench", "train_data": "none", "backbone_weights": "none"}
    set_metadata(model, build_metadata(info, input_size=(size, size), exporter="dynamo", opset=18))
    onnx.save(model, str(path))


def _load_average() -> float | None:
    import os

    try:
        return float(os.getloadavg()[0])
    except (OSError, AttributeError):
        return None


def _cpu_count() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
