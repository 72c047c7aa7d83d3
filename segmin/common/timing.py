"""Latency measurement: one timing loop for every benchmark, so all of them time the same thing.

Only the call itself is inside the timed region: picking the next input, warm-up calls and the
bookkeeping stay outside it, so a 0.2 ms navigator step and a 30 ms ONNX frame are measured alike.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Latency:
    """Per-call latency, milliseconds."""

    median_ms: float
    p95_ms: float
    runs: int

    @classmethod
    def of_seconds(cls, seconds: Sequence[float] | np.ndarray) -> Latency:
        """Median and 95th percentile of per-call wall times given in seconds."""
        samples = np.asarray(seconds, dtype=float)
        return cls(float(np.median(samples) * 1e3), float(np.percentile(samples, 95) * 1e3), int(samples.size))

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def time_calls(
    call: Callable[..., Any], runs: int = 50, warmup: int = 5, inputs: Sequence[Any] | None = None
) -> np.ndarray:
    """Wall time in seconds of each of `runs` calls, after `warmup` untimed calls.

    Without `inputs` every call is `call()`; with them, call i is `call(inputs[i % len(inputs)])`
    (warm-up calls cycle the same way), and the input is picked before the clock starts.
    """
    if inputs is not None and not len(inputs):
        raise ValueError("time_calls: `inputs` is empty")
    for i in range(warmup):
        call() if inputs is None else call(inputs[i % len(inputs)])
    times = np.empty(runs)
    for i in range(runs):
        if inputs is None:
            start = time.perf_counter()
            call()
        else:
            item = inputs[i % len(inputs)]
            start = time.perf_counter()
            call(item)
        times[i] = time.perf_counter() - start
    return times


def interleaved_calls(calls: Mapping[str, Callable[[], Any]], runs: int = 50, rounds: int = 3) -> dict[str, Latency]:
    """Latency of several calls timed in alternating rounds, so load from others hits all alike."""
    samples: dict[str, list[float]] = {name: [] for name in calls}
    per_round = max(1, runs // rounds)
    for _ in range(rounds):
        for name, call in calls.items():
            samples[name].extend(time_calls(call, runs=per_round, warmup=3))
    return {name: Latency.of_seconds(s) for name, s in samples.items()}
