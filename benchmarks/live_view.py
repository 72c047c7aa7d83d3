"""`python -m benchmarks live-view`: what the live view costs the runtime, as a share of its frame time.

The runtime (`RowFollower`: the ONNX model, SegMinD at the paper's 20 Hz masks / 5 Hz commands)
steps through a 30 Hz sequence of camera-sized frames, alone and then with `--live`'s publisher
(`live.publisher.LiveView`) after every step while a protocol client in a process of its own
(as Foxglove would be) subscribes to every channel. The two alternate for `rounds`, so a change
in the machine's load falls on both. The cost is measured in CPU time (the process's, all its
threads: the runtime's, onnxruntime's and the WebSocket server's): the extra CPU per frame with
the view against the runtime's CPU per frame alone, the share the target bounds. On a loaded
machine wall-clock times mostly measure the wait for a core; they are printed too, as the
frame times (the client's own CPU, in its process, is in neither). The machine's load is
printed before and after.
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
from segmin.nav_eval.ros2.topics import CMD_VEL, OVERLAY
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


def _run(runtime: RowFollower, frames: list, live: LiveView | None) -> tuple[float, float]:
    """(wall-clock s, process CPU s) per frame of the runtime and, given one, the live view's step."""
    runtime.reset()
    wall, cpu = time.perf_counter(), time.process_time()
    for t, rgb, depth in frames:
        output = runtime.step(rgb, depth, t)
        if live is not None:
            live.step(t, rgb, output, runtime.navigator)
    return (time.perf_counter() - wall) / len(frames), (time.process_time() - cpu) / len(frames)


def bench_live_view(model: str | Path, frames: int, rounds: int, size: tuple[int, int], threads: int) -> str:
    """The report (see the module docstring)."""
    config = FollowerConfig(NavigatorConfig(method="segmind", depth_threshold=5.0))
    # No busy-waiting between runs, as the node runs it (inference_spin off): spinning would add CPU time
    # to the runtime alone and shrink the share.
    segmenter = OnnxSegmenter(resolve_model(model), threads=threads, spin=False)
    runtime = RowFollower(segmenter, make_navigator(config))
    sequence = _frames(frames, *size)
    load_before = load_average()
    port = free_port()
    spawn: Any = multiprocessing.get_context("spawn")
    ready, stop, counts = spawn.Event(), spawn.Event(), spawn.Queue()
    alone: list[tuple[float, float]] = []
    viewed: list[tuple[float, float]] = []
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
    wall_alone, cpu_alone = np.mean(alone, axis=0)
    wall_viewed, cpu_viewed = np.mean(viewed, axis=0)
    share = float(cpu_viewed / cpu_alone - 1.0)
    overlays = received.get(OVERLAY, 0)
    return "\n".join(
        [
            f"python -m benchmarks live-view: {frames} frames of {size[0]}x{size[1]} at {HZ:g} Hz x {rounds} "
            f"round(s), segmind, {Path(str(model)).name}, {threads} thread(s)",
            f"machine: {load_before} before, {load_average()} after",
            f"runtime alone: {cpu_alone * 1e3:.2f} ms CPU/frame, {wall_alone * 1e3:.2f} ms wall/frame "
            f"(rounds, CPU: {_ms([c for _, c in alone])})",
            f"runtime + live view, a client subscribed: {cpu_viewed * 1e3:.2f} ms CPU/frame, "
            f"{wall_viewed * 1e3:.2f} ms wall/frame (rounds, CPU: {_ms([c for _, c in viewed])})",
            f"live view cost: {share:+.1%} of the runtime's CPU per frame (target < {TARGET:.0%}: "
            f"{'met' if share < TARGET else 'MISSED'}); wall clock {wall_viewed / wall_alone - 1.0:+.1%}",
            f"client received {overlays} of {frames * rounds} overlay frames, {received.get(CMD_VEL, 0)} commands",
        ]
    )


def _ms(values: list[float]) -> str:
    return " ".join(f"{v * 1e3:.2f}" for v in values)
