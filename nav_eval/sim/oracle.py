"""The oracle segmenter: the simulator's exact vegetation mask, no network.

It tells perception errors from control errors: a run that fails with the oracle fails because
of the controller, the robot or the world; one that fails only with the model fails because of
the model.

How the simulator feeds it: a segmenter may implement `segment_frame(frame)`, taking the whole
`RenderedFrame` (rgb, depth, exact mask). The simulator calls `segment_frame` when a segmenter
has it and `segment(frame.rgb)` otherwise (the `Segmenter` protocol of nav_eval.segmenter, e.g.
`OnnxSegmenter`). An RGB image alone does not carry the exact mask, so `segment(rgb)` raises.
"""

from __future__ import annotations

from typing import Any

import numpy as np


class OracleSegmenter:
    """Returns the rendered frame's exact vegetation mask."""

    name = "oracle"

    def segment_frame(self, frame: Any) -> np.ndarray:
        return np.asarray(frame.mask, dtype=bool)

    def probabilities_frame(self, frame: Any) -> np.ndarray:
        return np.asarray(frame.mask, dtype=np.float32)

    def segment(self, rgb: np.ndarray) -> np.ndarray:
        raise TypeError("OracleSegmenter needs the rendered frame: call segment_frame(frame), not segment(rgb)")

    def probabilities(self, rgb: np.ndarray) -> np.ndarray:
        raise TypeError("OracleSegmenter needs the rendered frame: call probabilities_frame(frame)")


def segment_frame(segmenter: Any, frame: Any) -> np.ndarray:
    """The one place the simulator asks a segmenter for a mask (see the module docstring)."""
    if hasattr(segmenter, "segment_frame"):
        return np.asarray(segmenter.segment_frame(frame), dtype=bool)
    return np.asarray(segmenter.segment(frame.rgb), dtype=bool)
