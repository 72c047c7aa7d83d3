"""`python -m benchmarks litert`: LiteRT files' frame time side by side, and what XNNPACK runs of each.

Why: LiteRT (XNNPACK on the CPU) is what Raspberry-Pi-class robot computers run first, and an
INT8 file is only worth shipping when it is faster than the fp32 one. Absolute milliseconds on
a shared machine move with the load, so the files are timed in alternating rounds in one process,
for each thread count asked, and reported as a ratio to the first file with the load average
before and after.

Beside the times it prints how XNNPACK took each file: its number of partitions (1 when XNNPACK
runs the whole graph) and the ops left to LiteRT's own kernels between them. Each op left out
splits the graph; for a quantised file these are the ops XNNPACK has no int8 kernel for, the
usual reason an INT8 file is slower than fp32. Any .tflite file can be timed: a segmin file takes
uint8 frames; a float32 input gets the frame /255 and ImageNet-normalised (how the paper's node
feeds its models).
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.machine import load_average
from segmin.common.timing import time_calls
from segmin.data.model_input import IMAGENET_MEAN, IMAGENET_STD
from segmin.export import litert_file


@dataclass(frozen=True)
class LiteRtSpeedOptions:
    """What `python -m benchmarks litert` takes (benchmarks/cli.py has the command-line help)."""

    models: tuple[Path, ...]
    threads: tuple[int, ...] = (2, 1)
    rounds: int = 6
    runs: int = 240

    def __post_init__(self) -> None:
        if not self.models:
            raise ValueError("--models: give at least one .tflite file")
        for path in self.models:
            if not Path(path).is_file():
                raise FileNotFoundError(f"--models {path}: no such file")
        if not self.threads or min(self.threads) < 1:
            raise ValueError(f"--threads {list(self.threads)}: each must be >= 1")
        if self.rounds < 1 or self.runs < self.rounds:
            raise ValueError(f"--rounds {self.rounds} / --runs {self.runs}: need 1 <= rounds <= runs")


def xnnpack_partitions(interpreter: Any) -> tuple[int, Counter[str]]:
    """(XNNPACK partitions, op name -> count of ops XNNPACK left to LiteRT) of an allocated interpreter.

    The interpreter lists every node of the graph and one DELEGATE node per XNNPACK partition,
    whose inputs and outputs are the partition's boundary tensors. An op XNNPACK took produces
    tensors inside its partition or on its boundary; an op left out produces a tensor that a
    partition, the graph output or another op left out reads, and no partition outputs it.
    (`_get_ops_details` is LiteRT's own listing, the one its Python API has.)
    """
    ops = interpreter._get_ops_details()
    partitions = [op for op in ops if op["op_name"] == "DELEGATE"]
    nodes = [op for op in ops if op["op_name"] != "DELEGATE"]
    produced_by_partitions = {t for op in partitions for t in op["outputs"]}
    read = {t for op in partitions for t in op["inputs"]} | {d["index"] for d in interpreter.get_output_details()}
    left: dict[int, str] = {}
    changed = True
    while changed:  # from the graph's end backwards: an op left out may feed another one left out
        changed = False
        for op in nodes:
            outputs = set(op["outputs"])
            if op["index"] in left or outputs & produced_by_partitions or not outputs & read:
                continue
            left[op["index"]] = op["op_name"]
            read |= {t for t in op["inputs"] if t >= 0}
            changed = True
    return len(partitions), Counter(left.values())


def op_census(path: str | os.PathLike[str]) -> Counter[str]:
    """ "OP dtype" -> count over the file's main graph, the dtype being the op's first input's
    (e.g. "HARD_SWISH int8" vs "HARD_SWISH float32"): which ops a quantised file keeps float."""
    from ai_edge_litert import schema_py_generated as schema

    names = {v: k for k, v in vars(schema.BuiltinOperator).items() if not k.startswith("_")}
    dtypes = {v: k.lower() for k, v in vars(schema.TensorType).items() if not k.startswith("_")}
    model = schema.Model.GetRootAs(Path(path).read_bytes(), 0)
    graph = model.Subgraphs(0)
    census: Counter[str] = Counter()
    for i in range(graph.OperatorsLength()):
        op = graph.Operators(i)
        code = model.OperatorCodes(op.OpcodeIndex())
        name = names.get(max(code.BuiltinCode(), code.DeprecatedBuiltinCode()), "CUSTOM")
        first = op.Inputs(0) if op.InputsLength() else -1
        census[f"{name} {dtypes[graph.Tensors(first).Type()]}" if first >= 0 else name] += 1
    return census


def _frame(details: dict[str, Any]) -> np.ndarray:
    """A fixed random frame in the input's type: uint8, or float32 /255 and ImageNet-normalised."""
    shape = tuple(int(v) for v in details["shape"])
    rgb = np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
    if details["dtype"] == np.uint8:
        return rgb
    return ((rgb / 255.0 - np.array(IMAGENET_MEAN)) / np.array(IMAGENET_STD)).astype(np.float32)


def _invoke(interpreter: Any, index: int, frame: np.ndarray) -> None:
    interpreter.set_tensor(index, frame)
    interpreter.invoke()


def run_litert_speed(options: LiteRtSpeedOptions) -> dict[int, dict[str, float]]:
    """Print (and return, {threads: {file: median ms}}) each file's frame time per thread count."""
    names = [str(path) for path in options.models]
    for name in names:
        interpreter = litert_file.make_interpreter(name, threads=1)
        partitions, left = xnnpack_partitions(interpreter)
        left_text = ", ".join(f"{op} x{n}" for op, n in sorted(left.items())) or "none"
        print(
            f"{name}: {os.path.getsize(name) / 1e6:.1f} MB, XNNPACK partitions {partitions}, ops left out: {left_text}"
        )
    medians: dict[int, dict[str, float]] = {}
    for threads in options.threads:
        calls = {}
        for name in names:
            interpreter = litert_file.make_interpreter(name, threads=threads)
            (details,) = interpreter.get_input_details()
            calls[name] = partial(_invoke, interpreter, details["index"], _frame(details))
        samples: dict[str, list[float]] = {name: [] for name in names}
        before = load_average()
        for _ in range(options.rounds):
            for name, call in calls.items():
                samples[name].extend(time_calls(call, runs=options.runs // options.rounds, warmup=3))
        print(f"{threads} thread(s), {options.rounds} alternating rounds; before: {before}, after: {load_average()}")
        medians[threads] = {name: float(np.median(s) * 1e3) for name, s in samples.items()}
        first = medians[threads][names[0]]
        for name in names:
            p95 = float(np.percentile(samples[name], 95) * 1e3)
            median = medians[threads][name]
            print(f"  {median:7.2f} ms median  {p95:7.2f} ms p95  {median / first:5.2f}x  {name}")
    return medians
