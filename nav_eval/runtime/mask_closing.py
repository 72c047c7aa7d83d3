"""The navigator's optional mask closing, at one scale whatever the camera.

A model's masks have small holes inside a crown (bare branches, gaps between leaves) that the
paper's column histograms read as free columns. Closing each mask with a disc fills them. The
radius is given in pixels at `REFERENCE_WIDTH` (the simulator's camera and the models' input
width), so one value means the same on a 224 px simulated camera and a 640 x 480 RealSense: a
mask of another width is closed at the reference width and scaled back. That also keeps the cost
flat (a disc of 23 px on a 640 px mask takes ten times longer than 8 px at 224). Vegetation is
never removed: the result is the mask or-ed with its closing.
"""

from __future__ import annotations

import cv2
import numpy as np

from segmin.data.canopy_region import canopy_region

REFERENCE_WIDTH = 224


def close_mask(mask: np.ndarray, radius: int) -> np.ndarray:
    """`mask` (bool H x W) closed with a disc of `radius` px at `REFERENCE_WIDTH`; itself when 0."""
    if radius == 0:
        return mask
    height, width = mask.shape
    if width == REFERENCE_WIDTH:
        return canopy_region(mask, radius)
    scaled_height = max(1, round(height * REFERENCE_WIDTH / width))
    # Area averaging (rounded, so a majority vote) when shrinking; nearest when enlarging.
    shrink = cv2.INTER_AREA if width > REFERENCE_WIDTH else cv2.INTER_NEAREST
    scaled = cv2.resize(mask.astype(np.uint8), (REFERENCE_WIDTH, scaled_height), interpolation=shrink)
    closed = cv2.resize(canopy_region(scaled, radius), (width, height), interpolation=cv2.INTER_NEAREST)
    return mask | closed.astype(bool)
