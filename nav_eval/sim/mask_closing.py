"""Any segmenter's masks as the canopy region: closed before the navigator sees them.

The models learn the canopy region (`data.label_closing`: the rendered mask closed with a disc,
which fills the branches and small gaps inside a crown), while the oracle returns the exact
mask. Closing the oracle's masks the same way (`perception.mask_closing`) drives the simulator
with a perfect model of that label, so a closed-loop failure can be put down either to the
label or to the model's own errors (docs/guide/closed-loop.md).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from segmin.common.mask_closing import canopy_region, check_closing_radius
from segmin.nav_eval.sim.config import Perception
from segmin.nav_eval.sim.protocols import FrameSegmenter, SimFrame


class ClosedMasks(FrameSegmenter):
    """The wrapped segmenter's masks closed with a disc of `radius` px (`canopy_region`)."""

    def __init__(self, segmenter: FrameSegmenter, radius: int) -> None:
        self.segmenter = segmenter
        self.reads_colour = segmenter.reads_colour
        self.radius = check_closing_radius(radius, "perception.mask_closing")

    def segment_frame(self, frame: SimFrame) -> np.ndarray:
        return self._close(self.segmenter.segment_frame(frame))

    def prepare_frame(self, frame: SimFrame) -> Callable[[], np.ndarray]:
        """The wrapped segmenter's split (a model keeps its helper thread), closed at the end."""
        finish = self.segmenter.prepare_frame(frame)
        return lambda: self._close(finish())

    def _close(self, mask: np.ndarray) -> np.ndarray:
        return canopy_region(np.asarray(mask, dtype=bool), self.radius)


def with_closing(segmenter: FrameSegmenter, perception: Perception) -> FrameSegmenter:
    """`segmenter` wrapped as perception.mask_closing asks (itself when the radius is 0)."""
    if perception.mask_closing == 0:
        return segmenter
    return ClosedMasks(segmenter, perception.mask_closing)
