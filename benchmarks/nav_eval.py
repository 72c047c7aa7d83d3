"""`python -m benchmarks nav-eval`: how fast the closed loop runs, and what the full matrix costs.

One run on one field with the ONNX segmenter on one thread (what each of 2 workers gets on the
2-core machine), timed per stage: rendering, segmentation (on a helper thread, overlapping the
next render), navigator, and the rest. The figure of merit is simulated seconds per wall-clock
second; the full matrix (5 fields x 3 methods x 3 runs) is estimated from it, or measured with
`--matrix`. Both are printed against `TARGETS`. Each render backend (`--backends`) drives the
same run, taking turns (`--rounds` times), so the ratio between them is measured under the same
load.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.machine import usable_cores
from segmin.common.speed_targets import SpeedTarget, verdict_lines
from segmin.data.synth.render import BACKENDS
from segmin.nav_eval.bench.navigator import untrained_onnx
from segmin.nav_eval.sim.config import NavEvalConfig

TARGETS: tuple[SpeedTarget, ...] = (
    SpeedTarget("realtime_factor", "closed loop", 8.0, "x real time", at_least=True),
    SpeedTarget("matrix_minutes", "full matrix estimate", 6.0, "min"),
)
# Simulated seconds of the full matrix: SegMin / SegMinD need ~42 s for 20 m at ~0.48 m/s (45 s
# with the start), SegZeros may run to its 60 s limit; 5 fields x 3 runs each.
MATRIX_SIM_S = 5 * 3 * (2 * 45.0) + 5 * 3 * 60.0


@dataclass(frozen=True)
class NavEvalBenchOptions:
    """What `python -m benchmarks nav-eval` takes (benchmarks/cli.py has the command-line help)."""

    config: NavEvalConfig
    model: str | None = None  # .onnx file or 'oracle'; None: an untrained model exported for timing
    field: str = "straight_vineyard"
    method: str = "segmind"
    seconds: float = 20.0  # simulated seconds to drive
    threads: int = 1  # onnxruntime threads
    seed: int = 0
    matrix: bool = False  # also run and time the full matrix
    workers: int = 2  # for the matrix (estimated and measured)
    out: Path | None = None  # the matrix's outputs (default: a temporary folder)
    backends: tuple[str, ...] = BACKENDS  # render backends, in turn; the matrix runs with the last
    rounds: int = 1  # turns of every backend

    def __post_init__(self) -> None:
        unknown = [b for b in self.backends if b not in BACKENDS]
        if unknown or not self.backends:
            raise ValueError(f"--backends {' '.join(self.backends)}: each must be one of {', '.join(BACKENDS)}")
        if self.rounds < 1:
            raise ValueError(f"--rounds {self.rounds}: must be >= 1")
        if not self.seconds > 0:
            raise ValueError(f"--seconds {self.seconds}: must be > 0")
        for name in ("threads", "workers"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name} {getattr(self, name)}: must be >= 1")


class _Timed:
    """Wraps one method of an object and accumulates its wall time."""

    def __init__(self, target: Any, method: str) -> None:
        self.calls, self.seconds = 0, 0.0
        original = getattr(target, method)

        def wrapper(*a: Any, **k: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return original(*a, **k)
            finally:
                self.seconds += time.perf_counter() - t0
                self.calls += 1

        setattr(target, method, wrapper)

    def ms(self) -> float:
        return 1000.0 * self.seconds / max(self.calls, 1)


def bench_one_run(
    model: str, field: str, method: str, seconds: float, config: Any, threads: int = 1, seed: int = 0
) -> dict[str, Any]:
    """Drive `seconds` of simulated time and return the timing breakdown."""
    from segmin.nav_eval.evaluation.rollout import run_episode
    from segmin.nav_eval.sim.factories import FieldContext, make_follower, make_segmenter, make_simulator

    config = dataclasses.replace(
        config,
        run=dataclasses.replace(
            config.run, time_limit_s=seconds, stall_time_s=10 * seconds, length_m=max(config.run.length_m, 1.0)
        ),
    )
    t0 = time.perf_counter()
    ctx = FieldContext(field, config)
    # The gl backend opens its context and uploads the world at the first frame; a worker does
    # that once for all its runs, so it counts with the field's build, not in the run's time.
    _ = ctx.renderer.raster
    build_s = time.perf_counter() - t0
    segmenter = make_segmenter(model, threads)
    simulator = make_simulator(ctx, config)
    follower = make_follower(method, ctx.depth_threshold, config)
    navigator = follower.navigator
    render = _Timed(ctx.renderer, "render")
    seg = _Timed(segmenter, next(m for m in ("segment_prepared", "segment_frame", "segment") if hasattr(segmenter, m)))
    nav = _Timed(navigator, "command")
    t0, cpu0 = time.perf_counter(), time.process_time()
    episode = run_episode(simulator, follower, segmenter, seed)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    sim = float(episode.trajectory.t[-1])
    ctx.close()
    # Segmentation overlaps rendering (nav_eval.sim): "other" is the wall time left after rendering
    # and the navigator, i.e. the robot, the checks and the segmentation not hidden behind a render.
    other = max(0.0, wall - render.seconds - nav.seconds)
    return {
        "field": field,
        "method": method,
        "model": model,
        "sim_s": sim,
        "wall_s": wall,
        "realtime_factor": sim / wall if wall > 0 else float("inf"),
        "world_build_s": build_s,
        "frames": render.calls,
        "render_ms": render.ms(),
        "segment_ms": seg.ms(),
        "navigator_ms": nav.ms(),
        "commands": nav.calls,
        "other_ms_per_sim_s": 1000 * other / max(sim, 1e-9),
        # CPU time of every thread (the renderer's and the segmenter's too) per simulated second
        "cpu_ms_per_sim_s": 1000 * cpu / max(sim, 1e-9),
        "reason": episode.reason,
        "resolution": f"{ctx.camera.width}x{ctx.camera.height}",
    }


def _with_backend(config: NavEvalConfig, backend: str) -> NavEvalConfig:
    """`auto` is what a run gets with no backend setting: each field's own (gl where EGL opens)."""
    chosen = None if backend == "auto" else backend
    return dataclasses.replace(config, render=dataclasses.replace(config.render, backend=chosen))


def bench_nav_eval(options: NavEvalBenchOptions) -> dict[str, Any]:
    """Time one run per backend and round, print each breakdown, then per backend the median real-time
    factor, the matrix estimate and the targets, and the ratio to the first backend; returns the
    median figures per backend."""
    from segmin.common.machine import load_average

    factors: dict[str, list[float]] = {b: [] for b in options.backends}
    with tempfile.TemporaryDirectory() as tmp:
        model = options.model or _untrained_for_timing(Path(tmp))
        for turn in range(options.rounds):
            for backend in options.backends:
                print(f"--- render backend {backend}, round {turn + 1}/{options.rounds}, {load_average()}")
                config = _with_backend(options.config, backend)
                r = bench_one_run(
                    model, options.field, options.method, options.seconds, config, options.threads, options.seed
                )
                _print_run(r, options.threads)
                factors[backend].append(r["realtime_factor"])
        print(f"--- summary ({options.workers} workers for the matrix estimate, perfect scaling), {load_average()}")
        figures = {}
        for backend, values in factors.items():
            factor = float(np.median(values))
            estimate = MATRIX_SIM_S / (factor * options.workers) / 60.0
            ratio = factor / float(np.median(factors[options.backends[0]]))
            print(
                f"{backend:5s}: {factor:.2f}x real time (median of {len(values)}), {ratio:.2f}x the "
                f"{options.backends[0]} backend; full matrix estimate (~{MATRIX_SIM_S / 60:.0f} simulated min) "
                f"{estimate:.1f} min"
            )
            for line in verdict_lines(TARGETS, {"realtime_factor": factor, "matrix_minutes": estimate}):
                print(f"  {line}")
            figures[backend] = {"realtime_factor": factor, "matrix_minutes": estimate}
        if options.matrix:
            matrix_options = dataclasses.replace(options, config=_with_backend(options.config, options.backends[-1]))
            _time_matrix(model, matrix_options, options.out or Path(tmp) / "matrix")
    return figures


def _untrained_for_timing(folder: Path) -> str:
    t0 = time.perf_counter()
    model = str(untrained_onnx(folder))
    print(f"no --model: exported an untrained model for timing ({time.perf_counter() - t0:.1f} s)")
    return model


def _print_run(r: dict[str, Any], threads: int) -> None:
    """The run's figures, stage by stage."""
    print(
        f"field {r['field']}, method {r['method']}, model {Path(r['model']).name}, {r['resolution']}, "
        f"onnxruntime threads {threads}"
    )
    print(f"world build (with the renderer's context and buffers): {r['world_build_s']:.2f} s")
    print(
        f"simulated {r['sim_s']:.1f} s in {r['wall_s']:.1f} s wall: {r['realtime_factor']:.2f}x real time; "
        f"run ended: {r['reason']}"
    )
    print(
        f"per frame: render {r['render_ms']:.1f} ms x {r['frames']} frames, segment {r['segment_ms']:.1f} ms "
        f"(wall time on the helper thread, overlapping the next render; it includes waiting for "
        f"the GIL); navigator {r['navigator_ms']:.2f} ms x "
        f"{r['commands']} commands; robot, checks and unhidden segmentation "
        f"{r['other_ms_per_sim_s']:.1f} ms per simulated s"
    )
    render_bound = 1000.0 / (r["render_ms"] * r["frames"] / max(r["sim_s"], 1e-9))
    print(f"rendering alone would allow {render_bound:.2f}x real time at these rates")
    cores = usable_cores()
    print(
        f"CPU {r['cpu_ms_per_sim_s']:.0f} ms per simulated s (all threads): on {cores} cores no schedule "
        f"beats {1000.0 * cores / max(r['cpu_ms_per_sim_s'], 1e-9):.2f}x real time"
    )


def _time_matrix(model: str, options: NavEvalBenchOptions, out: Path) -> None:
    """Run the full matrix on `options.workers` and print what it took."""
    from segmin.nav_eval.evaluation.evaluate import run_evaluation

    t0 = time.perf_counter()
    results = run_evaluation(
        model,
        "all",
        "segmin,segmind,segzeros",
        3,
        out,
        options.workers,
        options.config,
        seed=options.seed,
        progress=True,
        plots=False,
    )
    wall = time.perf_counter() - t0
    sim = float(np.nansum([r.sim_time for r in results]))
    print(
        f"full matrix measured (render backend {options.config.render.backend}): {len(results)} runs, {sim / 60:.1f} simulated min in {wall / 60:.1f} min wall "
        f"on {options.workers} workers ({sim / wall:.2f}x real time overall)"
    )
