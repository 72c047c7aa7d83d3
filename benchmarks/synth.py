"""`python -m benchmarks synth`: frames/s written per world (1 and 2 workers), and 20 m vs 200 m rows.

Every render backend (`--backends`, default tiny and gl) measures each world in turn, so their
ratio is taken under the same load.

Per world: whole-run and steady frames/s of `render_dataset` (RGB + depth + mask PNGs written),
and the CPU milliseconds of rendering and encoding one frame in this process (independent of
other load). Then the per-frame render time of a straight vineyard 20 m and 200 m long: culling
should make it (nearly) independent of the world's size; the ratio is printed against `TARGETS`.
"""

from __future__ import annotations

import dataclasses
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
    """What `python -m benchmarks synth` takes (benchmarks/cli.py has the command-line help)."""

    camera: CameraModel
    frames: int = 120  # frames per measurement
    fields: tuple[str, ...] = TEST_FIELDS
    workers: tuple[int, ...] = (1, 2)
    backends: tuple[str, ...] = ("tiny", "gl")

    def __post_init__(self) -> None:
        if not self.backends or any(b not in ("tiny", "gl") for b in self.backends):
            raise ValueError(f"--backends {' '.join(self.backends)}: each must be tiny or gl")
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
        f"python -m benchmarks synth: {camera.width}x{camera.height}, RGB + depth + mask PNGs written, "
        f"{options.frames} frames per run, {load_average()}"
    )
    print("frames/s: whole run (incl. building the world in each worker) and steady (after the first task);")
    print("cpu ms/frame: render + encode in one process (CPU time, independent of other load)")
    header = f"{'world':20s} {'backend':7s} " + " ".join(
        f"{f'{w}w run':>8s} {f'{w}w steady':>10s}" for w in options.workers
    )
    print(header + f" {'cpu ms/frame':>13s}")
    for name, spec in specs.items():
        cells = {b: _world_row(_with_backend(spec, b), options) for b in options.backends}
        for backend, row in cells.items():
            print(
                f"{name:20s} {backend:7s} "
                + " ".join(f"{v:8.1f} {s:10.1f}" for v, s in row[:-1])
                + f" {row[-1][0]:13.1f}"
            )
        if len(cells) > 1:  # per cell: frames/s of the last backend / the first; CPU ms of the first / the last
            first, last = cells[options.backends[0]], cells[options.backends[-1]]
            ratios = " ".join(f"{b[0] / a[0]:7.2f}x {b[1] / a[1]:9.2f}x" for a, b in zip(first[:-1], last[:-1]))
            print(f"{'':20s} {'ratio':7s} {ratios} {first[-1][0] / last[-1][0]:12.2f}x", flush=True)
    results = {}
    for backend in options.backends:
        seconds = {length: _render_seconds_at_length(length, options, backend) for length in ROW_LENGTHS}
        ratio = seconds[ROW_LENGTHS[1]] / seconds[ROW_LENGTHS[0]]
        print(f"{backend}: 200 m / 20 m per-frame render time ratio (CPU): {ratio:.2f}")
        for target in TARGETS:
            print(target.verdict(ratio))
        results.update({f"{backend} {length:g} m": s for length, s in seconds.items()})
        results[f"{backend} length_ratio"] = ratio
    return results


def _with_backend(spec: WorldSpec, backend: str) -> WorldSpec:
    return dataclasses.replace(spec, render=dataclasses.replace(spec.render, backend=backend))


def _world_row(spec: WorldSpec, options: SynthBenchOptions) -> list[tuple[float, float]]:
    """One table row: (whole-run, steady) frames/s per worker count, then (CPU ms of one frame, 0)."""
    from segmin.data.synth.writer import FrameRenderer, RenderJob, encode_frame, render_dataset

    cells = []
    for workers in options.workers:
        with tempfile.TemporaryDirectory(prefix="segmin_bench_") as tmp:
            job = RenderJob(
                spec=spec, out=Path(tmp), frames=options.frames, camera=options.camera, workers=workers, progress=False
            )
            summary = render_dataset(job)
        cells.append((summary["fps"], summary["steady_fps"]))
    renderer = FrameRenderer(spec, options.camera, spec.seed, 10, True)
    try:
        started = time.process_time()
        n = min(options.frames, 40)
        for f in range(n):
            encode_frame(renderer.render(f))
        cpu_ms = 1000 * (time.process_time() - started) / n
    finally:
        renderer.close()
    return [*cells, (cpu_ms, 0.0)]


def _render_seconds_at_length(length: float, options: SynthBenchOptions, backend: str) -> float:
    """Mean CPU seconds per frame over the first 15 m of a straight vineyard `length` m long
    (the same poses relative to the camera at every length); prints the world's size and times."""
    import pybullet as p

    from segmin.data.synth.render import Renderer
    from segmin.data.synth.spec import load_world_spec
    from segmin.data.synth.world import build_world

    spec = load_world_spec("straight_vineyard", [f"rows.length={length}", f"render.backend={backend}"])
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
