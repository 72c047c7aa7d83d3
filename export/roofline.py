"""How close an exported graph runs to this machine's arithmetic rate, and what that implies.

LR-ASPP MobileNetV3-Large at 224 x 224 is dominated by 1 x 1 convolutions (matrix products), so
the machine's float32 matrix-multiply rate with the same thread count is a practical reference
for any fp32 runtime. `python -m benchmarks export` prints the graph's convolution FLOPs, the rate
onnxruntime achieves, the reference rate (torch's sgemm, best of before and after the timing),
and the latency a graph running at that rate would have. It is an estimate, not a proof: a
runtime's own kernels can beat torch's sgemm (the fraction is then above 100 %), and on a shared
VM both rates move with the host's load.
"""

from __future__ import annotations

import time
from pathlib import Path


def conv_flops(path: str | Path, batch: int = 1) -> int:
    """Multiply-add FLOPs (2 per MAC) of every Conv node of an ONNX file, for `batch` frames."""
    import onnx
    from onnx import shape_inference

    model = onnx.load(str(path))
    first_dim = model.graph.input[0].type.tensor_type.shape.dim[0]
    first_dim.Clear()
    first_dim.dim_value = int(batch)
    model = shape_inference.infer_shapes(model, data_prop=True)
    shapes = {
        value.name: [dim.dim_value for dim in value.type.tensor_type.shape.dim]
        for value in list(model.graph.value_info) + list(model.graph.output)
    }
    weights = {init.name: list(init.dims) for init in model.graph.initializer}
    total = 0
    for node in model.graph.node:
        if node.op_type != "Conv":
            continue
        kernel, output = weights.get(node.input[1]), shapes.get(node.output[0])
        if kernel is None:
            raise ValueError(f"{path}: Conv node {node.name!r} takes its weights from another node, not an initializer")
        if output is None or len(output) != 4 or 0 in output:
            raise ValueError(f"{path}: shape inference left the output of Conv node {node.name!r} unknown")
        out_channels, in_per_group, kh, kw = kernel
        total += 2 * out_channels * in_per_group * kh * kw * output[0] * output[2] * output[3]
    return total


def sgemm_gflops(threads: int, size: int = 1024, repeats: int = 20) -> float:
    """Best-of-3 GFLOP/s of a float32 size x size matrix product with `threads` torch threads."""
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(int(threads))
    try:
        a, b = torch.randn(size, size), torch.randn(size, size)
        for _ in range(3):
            a @ b
        best = 0.0
        for _ in range(3):
            start = time.perf_counter()
            for _ in range(repeats):
                a @ b
            seconds = (time.perf_counter() - start) / repeats
            best = max(best, 2.0 * size**3 / seconds / 1e9)
        return best
    finally:
        torch.set_num_threads(previous)


def floor_summary(flops: int, ort_ms: float, eager_ms: float, peak_gflops: float) -> dict[str, float]:
    """Achieved rate, its fraction of the reference rate, and the latency / ratio at that rate."""
    floor_ms = flops / (peak_gflops * 1e9) * 1e3
    achieved = flops / (ort_ms * 1e-3) / 1e9
    return {
        "conv_gflop": flops / 1e9,
        "achieved_gflops": achieved,
        "peak_gflops": peak_gflops,
        "fraction_of_peak": achieved / peak_gflops,
        "floor_ms": floor_ms,
        "floor_ratio_to_eager": floor_ms / eager_ms,
    }
