"""`segmin bench synth`: frames/s written per world (1 and 2 workers), and 20 m vs 200 m rows.

Per world: whole-run and steady frames/s of `render_dataset` (RGB + depth + mask PNGs written),
and the CPU milliseconds of rendering and encoding one frame in this process (independent of
other load). Then the per-frame render time of a straight vineyard 20 m and 200 m long: culling
should make it (nearly) independent of the world's size; the ratio is printed against `TARGETS`.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segmin.common.speed_targets import SpeedTarget
from segmin.data.synth.camera import CameraModel
from segmin.data.synth.spec import TEST_FIELDS, WorldSpec

TARGETS: tuple[SpeedTarget, ...] = (SpeedTarget("length_ratio", "200 m / 20 m per-frame render time", 1.5),)
ROW_LENGTHS = (20.0, 200.0)  # metres: the short and the long straight vineyard of the culling check


@dataclass(frozen=True)
class SynthBenchOptions:
    """What `segmin bench synth` takes (data/synth/cli.py has the command-line help)."""

    camera: CameraModel
    frames: int = 120  # frames per measurement
    fields: tuple[str, ...] = TEST_FIELDS
    workers: tuple[int, ...] = (1, 2)

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise ValueError(f"--frames {self.frames}: must be >= 1")
        if not self.workers or min(self.workers) < 1:
            raise ValueError(f"--workers {' '.join(map(str, self.workers))}: each must be >= 1")


def bench_synth(options: SynthBenchOptions) -> dict[str, float]:
    """Print the table and the row-length check as they are measured; returns the per-frame CPU
    seconds of each row length and their ratio."""
    from segmin.common.machine import load_average
    from segmin.data.synth.spec import load_world_spec

    specs = {name: load_world_spec(name) for name in options.fields}  # a bad name fails before the table
    camera = options.camera
    print(
        f"segmin bench synth: {camera.width}x{camera.height}, RGB + depth + mask PNGs written, "
        f"{options.frames} frames per run, {load_average()}"
    )
    print("frames/s: whole run (incl. building the world in each worker) and steady (after the first task);")
    print("cpu ms/frame: render + encode in one process (CPU time, independent of other load)")
    header = f"{'world':20s} " + " ".join(f"{f'{w}w run':>8s} {f'{w}w steady':>10s}" for w in options.workers)
    print(header + f" {'cpu ms/frame':>13s}")
    for name, spec in specs.items():
        print(_world_row(name, spec, options), flush=True)
    seconds = {length: _render_seconds_at_length(length, options) for length in ROW_LENGTHS}
    ratio = seconds[ROW_LENGTHS[1]] / seconds[ROW_LENGTHS[0]]
    print(f"200 m / 20 m per-frame render time ratio (CPU): {ratio:.2f}")
    for target in TARGETS:
        print(target.verdict(ratio))
    return {**{f"{length:g} m": s for length, s in seconds.items()}, "length_ratio": ratio}


def _world_row(name: str, spec: WorldSpec, options: SynthBenchOptions) -> str:
    """One table row: frames/s per worker count, and the CPU cost of one frame."""
    from segmin.data.synth.writer import FrameRenderer, RenderJob, encode_frame, render_dataset

    cells = []
    for workers in options.workers:
        with tempfile.TemporaryDirectory(prefix="segmin_bench_") as tmp:
            job = RenderJob(
                spec=spec, out=Path(tmp), frames=options.frames, camera=options.camera, workers=workers, progress=False
            )
            summary = render_dataset(job)
        cells.append(f"{summary['fps']:8.1f} {summary['steady_fps']:10.1f}")
    renderer = FrameRenderer(spec, options.camera, spec.seed, 10, True)
    try:
        started = time.process_time()
        n = min(options.frames, 40)
        for f in range(n):
            encode_frame(renderer.render(f))
        cpu_ms = 1000 * (time.process_time() - started) / n
    finally:
        renderer.close()
    return f"{name:20s} " + " ".join(cells) + f" {cpu_ms:13.1f}"


def _render_seconds_at_length(length: float, options: SynthBenchOptions) -> float:
    """Mean CPU seconds per frame over the first 15 m of a straight vineyard `length` m long
    (the same poses relative to the camera at every length); prints the world's size and times."""
    import pybullet as p

    from segmin.data.synth.render import Renderer
    from segmin.data.synth.spec import load_world_spec
    from segmin.data.synth.world import build_world

    spec = load_world_spec("straight_vineyard", [f"rows.length={length}"])
    client = p.connect(p.DIRECT)
    try:
        t0 = time.perf_counter()
        world = build_world(spec, client)
        build_s = time.perf_counter() - t0
        renderer = Renderer(world, options.camera)
        rng = np.random.default_rng(0)
        wall, cpu = [], []
        for _ in range(options.frames):
            x, y, yaw = world.gap_pose(world.eval_gap, float(rng.uniform(0.0, 15.0)))
            t, c = time.perf_counter(), time.process_time()
            renderer.render(x, y, yaw)
            wall.append(time.perf_counter() - t)
            cpu.append(time.process_time() - c)
        seconds = float(np.mean(cpu))
        print(
            f"row length {length:5.0f} m: {len(world.chunks):5d} chunks, "
            f"{sum(len(c.bodies) for c in world.chunks):5d} bodies, build {build_s:.1f} s, "
            f"render {1000 * seconds:.1f} ms/frame CPU (median wall {1000 * np.median(wall):.1f} ms)",
            flush=True,
        )
        return seconds
    finally:
        p.disconnect(client)
