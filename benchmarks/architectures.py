"""`python -m benchmarks architectures`: the candidate networks' onnxruntime frame time against the full network.

Why: the released models must run at or below the paper's model's frame time (its MobileNetV3
cut after `expanded_conv_12`: 3.0-3.3 ms with 2 threads at 224 px on the reference 2-core
machine, where torchvision's full network takes about 5.5 ms). Absolute milliseconds on a shared
machine move with the load, so every architecture x input size is exported with random weights
(latency does not depend on them), timed in alternating rounds in one session, and reported as a
ratio to the full network at the largest size asked (224 px by default); the targets are set on
that ratio and on the milliseconds.

Beside the times it prints what onnxruntime made of each graph (its optimised node count, and
how many of those are activations and squeeze-excitation pools), so a slow graph can be told
from a big network.
"""

from __future__ import annotations

import functools
import os
import tempfile
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.machine import load_average_1min
from segmin.common.speed_targets import SpeedTarget, verdict_lines, verdicts
from segmin.common.timing import time_calls
from segmin.models.architectures import ARCHITECTURE, ARCHITECTURES, check_architecture

# The chosen release network (configs/pipeline/release.yaml) against the paper model's 3.0-3.3 ms
# (= 0.55-0.6x of the full network's 5.5 ms on the reference machine).
RELEASE_ARCHITECTURE = "lraspp_mobilenet_v3_large_cut13"
TARGETS: tuple[SpeedTarget, ...] = (
    SpeedTarget("release_ratio", "release network at 224 px", 0.6, "x full network"),
    SpeedTarget("release_ms", "release network at 224 px median", 3.3, "ms"),
)
# What is counted in the optimised graph. onnxruntime's CPU provider turns convolutions into NCHWc
# Convs with the activation fused in (an `activation` attribute), and adds layout reorders around them.
COUNTED = ("Conv", "Conv+HardSwish", "Conv+HardSigmoid", "GlobalAveragePool", "Mul", "Reorder")


@dataclass(frozen=True)
class ModelSpeedOptions:
    """What `python -m benchmarks architectures` takes (benchmarks/cli.py has the command-line help)."""

    architectures: tuple[str, ...] = tuple(ARCHITECTURES)
    sizes: tuple[int, ...] = (224, 192)
    threads: int = 2
    runs: int = 200
    json: Path | None = None

    def __post_init__(self) -> None:
        for name in self.architectures:
            check_architecture(name, "--architectures")
        if not self.architectures or not self.sizes:
            raise ValueError("--architectures and --sizes need at least one value each")
        for size in self.sizes:
            if size < 32 or size % 16:
                raise ValueError(f"--sizes {size}: must be >= 32 and a multiple of 16 (the backbone's stride)")
        if self.threads < 1 or self.runs < 8:
            raise ValueError(f"--threads {self.threads} / --runs {self.runs}: need threads >= 1 and runs >= 8")


def interleaved(
    candidates: Mapping[str, Callable[[], object]], runs: int, rounds: int = 8
) -> dict[str, dict[str, float]]:
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


def run_model_speed(options: ModelSpeedOptions) -> dict[str, Any]:
    """Export, inspect and time every architecture x size; print the table and the targets."""
    from segmin.export.roofline import conv_flops
    from segmin.export.verify import make_session

    rng = np.random.default_rng(0)
    rows: dict[str, dict[str, Any]] = {}
    calls = {}
    load_before = load_average_1min()
    with tempfile.TemporaryDirectory(prefix="segmin-model-speed-") as tmp_dir:
        for arch in _with_baseline(options.architectures):
            for size in options.sizes:
                key = f"{arch} @ {size}"
                path, params = _export_random(arch, size, Path(tmp_dir))
                rows[key] = {
                    "architecture": arch,
                    "size": size,
                    "params": params,
                    "file_mb": path.stat().st_size / 1e6,
                    "conv_gflop": conv_flops(path) / 1e9,
                }
                rows[key]["graph"] = _optimised_ops(path, options.threads, Path(tmp_dir) / f"{arch}_{size}.opt.onnx")
                session = make_session(path, threads=options.threads)
                feed = {session.get_inputs()[0].name: rng.integers(0, 256, (1, size, size, 3), dtype=np.uint8)}
                calls[key] = functools.partial(session.run, None, feed)
        timings = interleaved(calls, runs=options.runs)
    load_after = load_average_1min()
    base_size = max(options.sizes)
    baseline = timings[f"{ARCHITECTURE} @ {base_size}"]
    for key, row in rows.items():
        row.update(
            timings[key],
            ratio=timings[key]["median_ms"] / baseline["median_ms"],
            ratio_min=timings[key]["min_ms"] / baseline["min_ms"],
        )
    summary = {
        "threads": options.threads,
        "baseline": f"{ARCHITECTURE} @ {base_size}",
        "load_average_1min": [load_before, load_after],
        "cores": os.cpu_count(),
        "rows": rows,
        "targets": _print(options, rows, base_size, (load_before, load_after)),
    }
    if options.json is not None:
        from segmin.common.atomic import write_json

        write_json(options.json, summary)
    return summary


def _with_baseline(architectures: tuple[str, ...]) -> list[str]:
    """The asked architectures, the full network (the ratios' base) first."""
    return [ARCHITECTURE, *(a for a in dict.fromkeys(architectures) if a != ARCHITECTURE)]


def _export_random(architecture: str, size: int, folder: Path) -> tuple[Path, int]:
    """The deployed graph (dynamo exporter, uint8 NHWC in) of a randomly initialised network."""
    import torch

    from segmin.export.onnx import export_graph
    from segmin.models import build_model

    torch.manual_seed(0)
    model = build_model("none", architecture=architecture).eval()
    path = folder / f"{architecture}_{size}.onnx"
    export_graph(model, path, input_size=(size, size))
    return path, sum(p.numel() for p in model.parameters())


def _optimised_ops(path: Path, threads: int, optimised: Path) -> dict[str, int]:
    """Node counts of the graph onnxruntime runs (all optimisations on, as OnnxSegmenter runs it)."""
    import onnx
    import onnxruntime as ort

    session_options = ort.SessionOptions()
    session_options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    session_options.intra_op_num_threads = threads
    session_options.optimized_model_filepath = str(optimised)
    session_options.log_severity_level = 3
    ort.InferenceSession(str(path), session_options, providers=["CPUExecutionProvider"])
    nodes = onnx.load(str(optimised)).graph.node
    ops: Counter[str] = Counter()
    for node in nodes:
        fused = next((a.s.decode() for a in node.attribute if a.name == "activation"), "")
        ops[node.op_type.removesuffix("Input").removesuffix("Output")] += 1  # ReorderInput/Output -> Reorder
        if fused:
            ops[f"{node.op_type}+{fused}"] += 1
    return {"nodes": len(nodes), **{op: ops.get(op, 0) for op in COUNTED}}


def _print(
    options: ModelSpeedOptions,
    rows: dict[str, dict[str, Any]],
    base_size: int,
    loads: tuple[float | None, float | None],
) -> dict[str, bool]:
    import onnxruntime as ort

    load = "unknown" if None in loads else f"{loads[0]:.2f} before, {loads[1]:.2f} after"
    print(
        f"benchmarks architectures: onnxruntime {ort.__version__}, batch 1, {options.threads} threads, "
        f"random weights, all candidates alternated in one session; load average (1 min) {load} "
        f"on {os.cpu_count()} cores"
    )
    print(
        f"{'architecture @ px':<38}{'params M':>9}{'MB':>6}{'GFLOP':>7}{'median ms':>10}{'p95 ms':>8}{'min ms':>8}"
        f"{f'x full@{base_size}':>11}{'(of min)':>9}  graph"
    )
    for key, row in rows.items():
        graph = ", ".join(f"{op} {n}" for op, n in row["graph"].items() if n)
        print(
            f"{key:<38}{row['params'] / 1e6:>9.2f}{row['file_mb']:>6.1f}{row['conv_gflop']:>7.3f}"
            f"{row['median_ms']:>10.2f}{row['p95_ms']:>8.2f}{row['min_ms']:>8.2f}{row['ratio']:>11.2f}"
            f"{row['ratio_min']:>9.2f}  {graph}"
        )
    print(
        "x full: median over the full network's median; (of min): the same for the minimums, which a "
        "loaded machine disturbs least. GFLOP: the graph's convolutions (2 per multiply-add)."
    )
    release = rows.get(f"{RELEASE_ARCHITECTURE} @ 224")
    if release is None or base_size != 224:
        print(f"targets: not checked (they need {RELEASE_ARCHITECTURE} and the full network at 224 px)")
        return {}
    figures = {"release_ratio": release["ratio"], "release_ms": release["median_ms"]}
    for line in verdict_lines(TARGETS, figures):
        print(line)
    return verdicts(TARGETS, figures)
