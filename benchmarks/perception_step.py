"""The robot-side perception + control step, timed by `python -m benchmarks export`.

One step is what the robot computer does per camera frame at the inference rate: `OnnxSegmenter`
(resize, onnxruntime, threshold) then `Navigator.step` with SegMinD. It lives here, beside the
segmenter and the navigator, so the export package's benchmark can time it without importing
anything downstream of export.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig
from segmin.nav_eval.runtime.segmenter import OnnxSegmenter

STEP_NAME = "full step: OnnxSegmenter + Navigator.step (SegMinD)"


def perception_step_candidates(onnx_path: Path, rgb: np.ndarray, threads: int) -> dict[str, Callable[[], object]]:
    """A timer for one full step on `rgb` with a depth ramp from 0.5 m (bottom) to 8 m (top)."""
    segmenter = OnnxSegmenter(onnx_path, threads=threads)
    navigator = Navigator(NavigatorConfig(method="segmind", depth_threshold=5.0))
    height, width = rgb.shape[:2]
    depth = np.linspace(8.0, 0.5, height, dtype=np.float32)[:, None].repeat(width, axis=1)

    def full_step() -> object:
        return navigator.step(segmenter.segment(rgb), depth)

    return {STEP_NAME: full_step}
