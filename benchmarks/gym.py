"""`python -m benchmarks gym`: steps per second of `segmin/RowFollow-v0`, alone and under
`gymnasium.make_vec` (sync and async, 1 and 2 envs), per observation option and render backend.

A step of a vector of N envs is N env steps: the figure is env steps per wall second. Every
setting builds its envs first (the field, a pybullet client each) and times only the steps;
episodes that end are reset (the vector's own autoreset), as a learner would see them. The
render backends take turns on each setting, so their ratio is measured under the same load.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from segmin.common.figures import format_figure
from segmin.common.machine import load_average

OBSERVATIONS: dict[str, tuple[str, ...]] = {
    "rgb+depth": ("rgb", "depth", "t", "attitude"),
    "mask+depth": ("mask", "depth"),
}
"""The observation options the bench times, by label."""


@dataclasses.dataclass(frozen=True)
class GymBenchRow:
    """One timed setting."""

    mode: str  # "single", "sync" or "async"
    num_envs: int
    observation: str
    size: int
    steps_per_s: float
    backend: str = "tiny"


def time_env(
    mode: str, num_envs: int, obs_keys: Sequence[str], size: int, steps: int, field: str, backend: str = "tiny"
) -> float:
    """Env steps per second of `steps` vector steps (or single-env steps) after one reset."""
    import gymnasium

    import segmin.envs

    options: dict[str, Any] = {  # the env's keyword arguments
        "field": field,
        "obs_keys": tuple(obs_keys),
        "size": size,
        # auto: no setting, the env's default (each field's own backend: gl where EGL opens)
        "overrides": [] if backend == "auto" else [f"render.backend={backend}"],
    }
    env: gymnasium.Env | gymnasium.vector.VectorEnv
    if mode == "single":
        env = gymnasium.make(segmin.envs.ROW_FOLLOW, **options)
        action = np.array([0.4, 0.0])
    else:
        # Async workers spawn: a forked worker of a process that already rendered with gl cannot render.
        spawn = {"context": "spawn"} if mode == "async" else None
        env = gymnasium.make_vec(
            segmin.envs.ROW_FOLLOW, num_envs=num_envs, vectorization_mode=mode, vector_kwargs=spawn, **options
        )
        action = np.tile([0.4, 0.0], (num_envs, 1))
    try:
        env.reset(seed=0)
        start = time.perf_counter()
        for _ in range(steps):
            _, _, terminated, truncated, _ = env.step(action)
            if mode == "single" and (terminated or truncated):
                env.reset()
        return steps * num_envs / (time.perf_counter() - start)
    finally:
        env.close()


def bench_gym(
    field: str, sizes: Sequence[int], steps: int, num_envs: Sequence[int], backends: Sequence[str] = ("tiny", "gl")
) -> list[GymBenchRow]:
    """Every (observation, size, mode, N) setting with each backend in turn, printed as it is timed."""
    settings = [("single", 1)] + [(mode, n) for mode in ("sync", "async") for n in num_envs]
    rows = []
    for label, keys in OBSERVATIONS.items():
        for size in sizes:
            for mode, n in settings:
                for backend in backends:
                    rate = time_env(mode, n, keys, size, steps, field, backend)
                    rows.append(GymBenchRow(mode, n, label, size, rate, backend))
                    print(
                        f"{label:>10} {size:>4}px {backend:>4} {mode:>6} N={n}: {rate:7.1f} env steps/s "
                        f"({load_average()})"
                    )
    return rows


def format_gym_rows(rows: Sequence[GymBenchRow]) -> str:
    """A markdown table, with each setting's rate against the single env's at its observation, size
    and backend, and against the first backend's at the same setting."""
    single = {(r.observation, r.size, r.backend): r.steps_per_s for r in rows if r.mode == "single"}
    first = rows[0].backend if rows else ""
    reference = {(r.observation, r.size, r.mode, r.num_envs): r.steps_per_s for r in rows if r.backend == first}
    lines = [
        f"| observation | size | backend | mode | envs | env steps/s | x single | x {first} |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.observation} | {r.size} | {r.backend} | {r.mode} | {r.num_envs} | {r.steps_per_s:.1f} "
            f"| {_ratio(r.steps_per_s, single.get((r.observation, r.size, r.backend)))} "
            f"| {_ratio(r.steps_per_s, reference.get((r.observation, r.size, r.mode, r.num_envs)))} |"
        )
    return "\n".join(lines + [f"\n{load_average()}"])


def _ratio(rate: float, to: float | None) -> str:
    """The rate as a multiple of `to`; n/a where nothing was timed to compare with."""
    return format_figure(rate / to if to else None, 2)
