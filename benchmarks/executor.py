"""`python -m benchmarks executor`: the Ray executor's overhead against the local pool, on the same jobs.

Two workloads, each run under both executors in turn (local, ray, ray, local, ... so that a
drift in the machine's load falls on both alike): a render of `frames` frames of one field and
a nav-eval of `runs` runs with the oracle. Ray is started once before the first timed run and
kept (as a cluster would be); its start is timed apart. The figure is ray seconds / local
seconds per workload, summed over the rounds.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path

from segmin.common.executor import LOCAL, Executor, connect_ray, import_ray
from segmin.common.machine import load_average

RAY = Executor("ray")


@dataclasses.dataclass(frozen=True)
class ExecutorBenchOptions:
    field: str = "straight_vineyard"
    frames: int = 200
    size: int = 224
    runs: int = 15
    workers: int = 2
    rounds: int = 2
    nav_overrides: tuple[str, ...] = ("run.length_m=5",)
    ray_address: str | None = None


def time_render(options: ExecutorBenchOptions, executor: Executor) -> float:
    """Seconds to render `frames` frames into a fresh folder."""
    from segmin.data.synth.camera import CameraModel
    from segmin.data.synth.spec import load_world_spec
    from segmin.data.synth.writer import RenderJob, render_dataset

    with tempfile.TemporaryDirectory(prefix="segmin_bench_") as tmp:
        job = RenderJob(
            spec=load_world_spec(options.field),
            out=Path(tmp),
            frames=options.frames,
            camera=CameraModel(width=options.size, height=options.size),
            workers=options.workers,
            progress=False,
            executor=executor,
        )
        return render_dataset(job)["seconds"]


def time_nav_eval(options: ExecutorBenchOptions, executor: Executor) -> float:
    """Seconds of a nav-eval of `runs` oracle runs (3 methods, runs / 3 runs each) with no figures."""
    from segmin.nav_eval.evaluation.evaluate import run_evaluation
    from segmin.nav_eval.runtime.methods import METHODS
    from segmin.nav_eval.sim.config import load_nav_config

    config = load_nav_config(None, list(options.nav_overrides))
    runs = max(1, options.runs // len(METHODS))
    with tempfile.TemporaryDirectory(prefix="segmin_bench_") as tmp:
        start = time.perf_counter()
        run_evaluation(
            "oracle",
            options.field,
            list(METHODS),
            runs,
            tmp,
            options.workers,
            config,
            progress=False,
            plots=False,
            executor=executor,
        )
        return time.perf_counter() - start


def bench_executor(options: ExecutorBenchOptions) -> dict[str, float]:
    """Print each timed run and the ray / local ratio per workload; return the ratios."""
    ray = import_ray()
    start = time.perf_counter()
    connected = connect_ray(options.ray_address)
    print(f"ray connected in {time.perf_counter() - start:.1f} s ({load_average()})", flush=True)
    totals = {(w, e): 0.0 for w in ("render", "nav-eval") for e in ("local", "ray")}
    try:
        for r in range(options.rounds):
            order = [("local", LOCAL), ("ray", RAY)]
            for name, executor in order if r % 2 == 0 else order[::-1]:
                for workload, timer in (("render", time_render), ("nav-eval", time_nav_eval)):
                    seconds = timer(options, executor)
                    totals[(workload, name)] += seconds
                    print(f"round {r + 1} {workload:8s} {name:5s}: {seconds:6.1f} s ({load_average()})", flush=True)
    finally:
        if connected:
            ray.shutdown()
    ratios = {w: totals[(w, "ray")] / totals[(w, "local")] for w in ("render", "nav-eval")}
    print(
        f"ray / local time: render {options.frames} frames {ratios['render']:.3f}, "
        f"nav-eval {options.runs} runs {ratios['nav-eval']:.3f} "
        f"({options.workers} workers, {options.rounds} rounds; {load_average()})"
    )
    return ratios
