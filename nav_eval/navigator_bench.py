"""`segmin bench navigator`: time one `Navigator.step` per method on one thread."""

from __future__ import annotations

import os

import numpy as np

from segmin.common.timing import time_calls
from segmin.nav_eval.demo_scenes import DEMO_SCENES, render_scene
from segmin.nav_eval.navigator import METHODS, Navigator, NavigatorConfig

TARGET_MEDIAN_MS = 0.2


def bench_navigator(*, size: int = 224, steps: int = 3000, warmup: int = 200) -> list[dict]:
    """Median and p95 milliseconds per step for each method, on a realistic vineyard frame."""
    frames = [render_scene(scene, size=size, seed=i) for i, scene in enumerate(DEMO_SCENES[:3])]
    rows = []
    for method in METHODS:
        navigator = Navigator(NavigatorConfig(method=method, depth_threshold=5.0, fuse_frames=3))
        ms = time_calls(lambda frame, nav=navigator: nav.step(*frame), runs=steps, warmup=warmup, inputs=frames) * 1e3
        rows.append({"method": method, "median_ms": float(np.median(ms)), "p95_ms": float(np.percentile(ms, 95))})
    return rows


def format_rows(rows: list[dict], size: int) -> str:
    lines = [f"Navigator.step at {size} x {size}, fuse_frames 3, one thread (target median <= {TARGET_MEDIAN_MS} ms)"]
    for row in rows:
        ratio = row["median_ms"] / TARGET_MEDIAN_MS
        lines.append(f"  {row['method']:<9} median {row['median_ms']:.3f} ms  p95 {row['p95_ms']:.3f} ms  "
                     f"({ratio:.2f}x the target budget)")
    return "\n".join(lines)


def single_thread_environment() -> None:
    """Pin numpy's thread pools to one thread (the benchmark measures one core)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
