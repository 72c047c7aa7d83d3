"""Depth-noise draws read from a fixed random field at a random window, instead of drawn per pixel.

Drawing a 224 x 224 frame's Gaussian noise and dropouts pixel by pixel costs about 0.5-0.8 ms on
one core: a fifth of a fast simulator step (the gl backend draws a mask + depth frame in about
2.5 ms). Here two fields are drawn once per process with a fixed seed, standard normal and uniform
on [0, 1), `FIELD_SIDE` pixels square; a frame takes the window at an offset drawn from the run's
generator (one call). Within a frame every pixel's draws are independent, as before; across frames
a pixel gets the same draw again only when the whole offset repeats (1 in about 3.4 million at 224
px), so the noise is as white in time as the sensor's model asks. What repeats is the field itself,
shifted: a pattern a learner could only exploit by memorising 32 MB of noise.
"""

from __future__ import annotations

import functools

import numpy as np

FIELD_SIDE = 2048
"""Side of the fields, pixels; a larger frame gets fields of its own size."""
FIELD_SEED = 20261205
"""The fields' fixed seed: every process, run and backend reads the same fields."""


@functools.cache
def noise_fields(side: int) -> tuple[np.ndarray, np.ndarray]:
    """The standard-normal and uniform float32 fields of `side` x `side` pixels (read-only)."""
    rng = np.random.default_rng(FIELD_SEED)
    normal = rng.standard_normal((side, side), dtype=np.float32)
    uniform = rng.random((side, side), dtype=np.float32)
    normal.flags.writeable = uniform.flags.writeable = False
    return normal, uniform


def field_window(rng: np.random.Generator, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The normal and uniform draws of a frame of `shape` (rows, columns): views of the fields at an
    offset drawn from `rng`."""
    rows, columns = shape
    normal, uniform = noise_fields(max(FIELD_SIDE, rows, columns))
    side = normal.shape[0]
    top, left = rng.integers(0, side - rows + 1), rng.integers(0, side - columns + 1)
    window = (slice(top, top + rows), slice(left, left + columns))
    return normal[window], uniform[window]
