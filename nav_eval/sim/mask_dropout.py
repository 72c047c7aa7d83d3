"""A weaker segmenter, simulated: a seeded share of the masks is corrupted before the navigator sees it.

Sweeping how good the model must be needs models of every quality; corrupting the masks of one
(the oracle's exact masks, or an exported model's) gives the same axis at no training cost.
`MaskDropout(segmenter, share, mode, seed)` wraps any `FrameSegmenter` (the simulator's
segmenters: the oracle, an exported model on frames) and is one itself; for
each mask it returns, draws whether to corrupt it (probability `share`, the run's seeded stream,
in the order the masks are computed, which a run fixes):

- "erode": the vegetation shrinks by a square erosion of 1/16 of the image width (14 px at 224),
  a model that misses thin foliage, the far end of the rows and the canopy's edges;
- "drop": the mask is empty, an inference that found nothing (or was lost).

The navigator ORs the last masks, so a single corrupted mask is often hidden by its neighbours;
what a share p does to a run is what the sweep measures.
"""

from __future__ import annotations

import cv2
import numpy as np

from segmin.nav_eval.sim.config import Perception
from segmin.nav_eval.sim.protocols import FrameSegmenter, SimFrame

MODES = ("erode", "drop")
ERODE_FRACTION = 1.0 / 16.0  # erosion kernel side as a share of the image width


class MaskDropout(FrameSegmenter):
    """Corrupts a seeded share of the wrapped segmenter's masks (see the module docstring)."""

    def __init__(self, segmenter: FrameSegmenter, share: float, mode: str = "erode", seed: int = 0) -> None:
        if not 0.0 <= share <= 1.0:
            raise ValueError(f"mask dropout share must be within [0, 1], got {share}")
        if mode not in MODES:
            raise ValueError(f"mask dropout mode {mode!r}: choose from {list(MODES)}")
        self.segmenter = segmenter
        self.reads_colour = segmenter.reads_colour
        self.share = float(share)
        self.mode = mode
        # Its own stream: the start, depth and actuator noise of the run (nav_eval.sim) stay the same.
        self._rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5E6D]))
        self.corrupted = 0  # masks corrupted so far
        self.masks = 0  # masks returned so far

    def segment_frame(self, frame: SimFrame) -> np.ndarray:
        """The wrapped segmenter's mask, corrupted with probability `share`."""
        mask = self.segmenter.segment_frame(frame)
        self.masks += 1
        if self._rng.random() >= self.share:
            return mask
        self.corrupted += 1
        return corrupt(mask, self.mode)


def corrupt(mask: np.ndarray, mode: str) -> np.ndarray:
    """The mask after one corruption of `mode` (a new array)."""
    if mode == "drop":
        return np.zeros_like(mask, dtype=bool)
    side = max(3, int(round(mask.shape[1] * ERODE_FRACTION)) | 1)
    kernel = np.ones((side, side), np.uint8)
    return cv2.erode(mask.astype(np.uint8), kernel).astype(bool)


def with_dropout(segmenter: FrameSegmenter, perception: Perception, seed: int) -> FrameSegmenter:
    """`segmenter` wrapped as perception.mask_dropout asks (itself when the share is 0)."""
    if perception.mask_dropout <= 0:
        return segmenter
    return MaskDropout(segmenter, perception.mask_dropout, perception.mask_dropout_mode, seed)
