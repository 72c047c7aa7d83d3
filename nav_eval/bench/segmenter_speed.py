"""`segmin bench model-speed`: a model's camera-frame-to-mask time in each runtime configuration,
as a ratio to the paper's TFLite model timed side by side.

Why this shape: absolute milliseconds move with the machine and its load, so every figure that
matters is a ratio to the paper's model measured in the same rotation. Each configuration runs in
a fresh process of its own for each turn (a robot runs one segmenter; a pool left spinning by the
previous configuration would slow the next), the configurations take turns round after round, and
a configuration's figure is the median of its rounds' medians. `--busy N` adds N processes that
keep a core half busy, as a robot's camera and motor drivers do: onnxruntime's spinning threads
fight them for the cores, which an idle machine never shows.

Both sides are timed from a 224 x 224 camera frame (the image resized once, before timing, so
that a large photo's resize does not hide the models) to the boolean mask: segmin's segmenter
(its checks, the graph with the normalisation inside it, the threshold) and the paper's model as
its node feeds it (/255 and the ImageNet normalisation in numpy, float NHWC, the per-frame
min-max and the 0.7 threshold).
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.machine import load_average, load_average_1min
from segmin.common.speed_targets import SpeedTarget, verdict_lines
from segmin.common.timing import time_calls

# The robot's default configuration against the paper's model, at each thread count.
TARGET = SpeedTarget("default_ratio", "the runtime's default configuration", 0.8, "x the paper's model")
PAPER_SIZE = 224  # the paper's node feeds its models 224 x 224
PAPER_THRESHOLD = 0.7
IMAGENET_MEAN = np.array([0.485, 0.456, 0.406], np.float32)
IMAGENET_STD = np.array([0.229, 0.224, 0.225], np.float32)
BUSY_DUTY_S = 0.005  # a busy process works this long, then sleeps as long: half a core


@dataclass(frozen=True)
class Setup:
    """One configuration: `kind` "paper" (the paper's TFLite), "onnx" or "litert" (segmin's
    segmenters); `spin` is onnxruntime's thread spinning (None where the runtime has no such switch)."""

    kind: str
    path: str
    threads: int
    spin: bool | None = None

    @property
    def label(self) -> str:
        spin = "" if self.spin is None else f", spinning {'on' if self.spin else 'off'}"
        name = {"paper": "paper TFLite", "onnx": "onnx", "litert": f"litert {Path(self.path).name}"}[self.kind]
        return f"{name} {self.threads} thread(s){spin}"


@dataclass(frozen=True)
class SetupFigure:
    """A configuration's median frame time (ms) over rounds, and each round's median."""

    setup: Setup
    median_ms: float
    round_medians_ms: tuple[float, ...]


def camera_frame(rgb: np.ndarray) -> np.ndarray:
    """The image as a camera at the models' input size would deliver it (INTER_AREA, as both resize)."""
    import cv2

    return cv2.resize(rgb, (PAPER_SIZE, PAPER_SIZE), interpolation=cv2.INTER_AREA)


def paper_segmenter(path: str, threads: int) -> Callable[[np.ndarray], np.ndarray]:
    """The paper's TFLite model as its node runs it: an RGB frame in, a boolean 224 x 224 mask out."""
    import cv2
    from ai_edge_litert.interpreter import Interpreter

    interpreter = Interpreter(model_path=path, num_threads=threads)
    interpreter.allocate_tensors()
    source = interpreter.get_input_details()[0]["index"]
    sink = interpreter.get_output_details()[0]["index"]

    def segment(rgb: np.ndarray) -> np.ndarray:
        small = cv2.resize(rgb, (PAPER_SIZE, PAPER_SIZE), interpolation=cv2.INTER_AREA)
        interpreter.set_tensor(
            source, ((small[None] / np.float32(255) - IMAGENET_MEAN) / IMAGENET_STD).astype(np.float32)
        )
        interpreter.invoke()
        y = interpreter.get_tensor(sink).reshape(PAPER_SIZE, PAPER_SIZE)
        span = float(y.max() - y.min())
        return (y - y.min()) / span >= PAPER_THRESHOLD if span > 0 else np.zeros(y.shape, bool)

    return segment


def _segmenter(setup: Setup) -> Callable[[np.ndarray], np.ndarray]:
    if setup.kind == "paper":
        return paper_segmenter(setup.path, setup.threads)
    from segmin.nav_eval.runtime.segmenter import load_segmenter

    # a file path: the runtime's loader picks the segmenter by its suffix (.onnx / .tflite)
    return load_segmenter(setup.path, threads=setup.threads, spin=bool(setup.spin)).segment


def time_setup(setup: Setup, frame: np.ndarray, warmup: int, runs: int) -> np.ndarray:
    """Seconds of each of `runs` frames after `warmup` (run inside the configuration's own process)."""
    return time_calls(_segmenter(setup), runs=runs, warmup=warmup, inputs=[frame])


def _busy(stop: Any, parent: int) -> None:
    """Half a core of work until `stop` is set or the bench that started it is gone (a robot's
    drivers beside the segmenter; a bench killed before it could set `stop` leaves no load behind)."""
    a = np.random.default_rng(0).random((64, 64))
    while not stop.is_set() and os.getppid() == parent:
        end = time.perf_counter() + BUSY_DUTY_S
        while time.perf_counter() < end:
            a = a @ a
            a /= np.abs(a).max()
        time.sleep(BUSY_DUTY_S)


@contextmanager
def busy_processes(count: int) -> Iterator[None]:
    """`count` background processes keeping half a core busy each, for the block's duration."""
    context = multiprocessing.get_context("spawn")
    stop = context.Event()
    workers = [context.Process(target=_busy, args=(stop, os.getpid()), daemon=True) for _ in range(count)]
    for worker in workers:
        worker.start()
    try:
        yield
    finally:
        stop.set()
        for worker in workers:
            worker.join(timeout=5)


def run_rounds(
    setups: Sequence[Setup], frame: np.ndarray, rounds: int, warmup: int, runs: int, say: Callable[[str], None] = print
) -> list[SetupFigure]:
    """Every configuration in its own fresh process, in turn, `rounds` times."""
    from concurrent.futures import ProcessPoolExecutor

    medians: dict[Setup, list[float]] = {setup: [] for setup in setups}
    context = multiprocessing.get_context("spawn")
    for turn in range(rounds):
        for setup in setups:
            with ProcessPoolExecutor(max_workers=1, mp_context=context) as pool:
                seconds = pool.submit(time_setup, setup, frame, warmup, runs).result()
            medians[setup].append(float(np.median(seconds) * 1e3))
            say(f"round {turn + 1}/{rounds} {setup.label}: {medians[setup][-1]:.2f} ms median ({load_average()})")
    return [SetupFigure(setup, float(np.median(values)), tuple(values)) for setup, values in medians.items()]


def format_figures(figures: Sequence[SetupFigure], default: Setup) -> list[str]:
    """A markdown table with each configuration's ratio to the paper's model at its thread count,
    then the target's verdict for the runtime's default configuration: `default` at every thread
    count (its `threads` is not compared)."""
    paper = {f.setup.threads: f.median_ms for f in figures if f.setup.kind == "paper"}
    lines = [
        f"the runtime's default: {default.label.replace(' 0 thread(s)', '')}",
        "| configuration | median ms | rounds (ms) | x the paper's model |",
        "|---|---|---|---|",
    ]
    for f in figures:
        reference = paper.get(f.setup.threads)
        ratio = f"{f.median_ms / reference:.2f}" if reference else "n/a"
        rounds = " ".join(f"{value:.2f}" for value in f.round_medians_ms)
        lines.append(f"| {f.setup.label} | {f.median_ms:.2f} | {rounds} | {ratio} |")
    for f in figures:
        same = (f.setup.kind, f.setup.path, f.setup.spin) == (default.kind, default.path, default.spin)
        if same and f.setup.threads in paper:
            default_ratio = f.median_ms / paper[f.setup.threads]
            figure = {TARGET.key: default_ratio}
            lines += [f"{f.setup.threads} thread(s): " + line for line in verdict_lines([TARGET], figure)]
    return lines


def write_json(path: Path, figures: Sequence[SetupFigure], options: dict[str, Any]) -> None:
    """The figures and the options they were measured with (written atomically)."""
    from segmin.common.atomic import write_json as write_json_atomic

    payload = {
        "options": options,
        "load_1min": load_average_1min(),
        "figures": [
            {
                **asdict(f.setup),
                "label": f.setup.label,
                "median_ms": f.median_ms,
                "round_medians_ms": f.round_medians_ms,
            }
            for f in figures
        ],
    }
    write_json_atomic(path, payload)
