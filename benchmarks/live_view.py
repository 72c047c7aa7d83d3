"""`python -m benchmarks live-view`: what the live view costs the runtime, as a share of its frame time.

The runtime (`RowFollower`: the ONNX model, SegMinD at the paper's 20 Hz masks / 5 Hz commands)
steps through a 30 Hz sequence of camera-sized frames, alone and then with `--live`'s publisher
(`live.publisher.LiveView`) after every step while a protocol client in a process of its own
(as Foxglove would be) subscribes to every channel. The two alternate for `rounds`, so a change
in the machine's load falls on both; the figure is the mean frame time of each and the ratio.
The machine's load is printed before and after: a loaded machine slows both and the ratio less.
"""

from __future__ import annotations

import multiprocessing
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.live_client import count_in_process, free_port
from segmin.common.machine import load_average
from segmin.nav_eval.live.publisher import LiveView
from segmin.nav_eval.live.server import LIVE_TYPES, LiveServer
from segmin.nav_eval.ros2 import topics
from segmin.nav_eval.runtime.follower import RowFollower
from segmin.nav_eval.runtime.follower_config import FollowerConfig, make_navigator
from segmin.nav_eval.runtime.navigator import NavigatorConfig
from segmin.nav_eval.runtime.segmenter import OnnxSegmenter
from segmin.nav_eval.runtime.shipped_models import resolve_model

HZ = 30.0
TARGET = 0.10  # the live view may cost the runtime under 10 % of its frame time


def _frames(count: int, width: int, height: int) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """A row seen head-on: green walls at the sides, a brown floor, depth 2-8 m; a little noise
    per frame so no two frames are the same (the runtime's frozen-image check stays quiet)."""
    rng = np.random.default_rng(0)
    base = np.zeros((height, width, 3), dtype=np.uint8)
    base[:] = (120, 90, 60)
    base[: height * 2 // 3, : width // 4] = base[: height * 2 // 3, -width // 4 :] = (40, 150, 50)
    depth = np.tile(np.linspace(2.0, 8.0, width, dtype=np.float32), (height, 1))
    frames = []
    for i in range(count):
        noise = rng.integers(0, 8, size=base.shape, dtype=np.uint8)
        frames.append((i / HZ, base + noise, depth))
    return frames


def _run(runtime: RowFollower, frames: list, live: LiveView | None) -> float:
    """Mean seconds per frame of the runtime (and the live view's step, given one)."""
    runtime.reset()
    start = time.perf_counter()
    for t, rgb, depth in frames:
        output = runtime.step(rgb, depth, t)
        if live is not None:
            live.step(t, rgb, output, runtime.navigator)
    return (time.perf_counter() - start) / len(frames)


def bench_live_view(model: str | Path, frames: int, rounds: int, size: tuple[int, int], threads: int) -> str:
    """The report (see the module docstring)."""
    config = FollowerConfig(NavigatorConfig(method="segmind", depth_threshold=5.0))
    runtime = RowFollower(OnnxSegmenter(resolve_model(model), threads=threads), make_navigator(config))
    sequence = _frames(frames, *size)
    load_before = load_average()
    port = free_port()
    spawn: Any = multiprocessing.get_context("spawn")
    ready, stop, counts = spawn.Event(), spawn.Event(), spawn.Queue()
    alone, viewed = [], []
    with LiveServer(LIVE_TYPES, port) as server:
        client = spawn.Process(target=count_in_process, args=(port, ready, stop, counts), daemon=True)
        client.start()
        if not ready.wait(30):
            raise RuntimeError("bench live-view: the protocol client did not subscribe within 30 s")
        live = LiveView(server)
        _run(runtime, sequence[: min(frames, 30)], None)  # warm-up: onnxruntime's first calls
        for _ in range(rounds):
            alone.append(_run(runtime, sequence, None))
            viewed.append(_run(runtime, sequence, live))
        time.sleep(0.5)
        stop.set()
        received = counts.get(timeout=30)
        client.join(timeout=10)
    mean_alone, mean_viewed = float(np.mean(alone)), float(np.mean(viewed))
    ratio = mean_viewed / mean_alone - 1.0
    overlays = received.get(topics.OVERLAY, 0)
    return "\n".join(
        [
            f"python -m benchmarks live-view: {frames} frames of {size[0]}x{size[1]} at {HZ:g} Hz x {rounds} "
            f"round(s), segmind, {Path(str(model)).name}, {threads} thread(s)",
            f"machine: {load_before} before, {load_average()} after",
            f"runtime alone: {mean_alone * 1e3:.2f} ms/frame (rounds: {_ms(alone)})",
            f"runtime + live view, a client subscribed: {mean_viewed * 1e3:.2f} ms/frame (rounds: {_ms(viewed)})",
            f"live view cost: {ratio:+.1%} of the frame time (target < {TARGET:.0%}: "
            f"{'met' if ratio < TARGET else 'MISSED'})",
            f"client received {overlays} of {frames * rounds} overlay frames, {received.get(topics.CMD_VEL, 0)} commands",
        ]
    )


def _ms(values: list[float]) -> str:
    return " ".join(f"{v * 1e3:.2f}" for v in values)
