"""Closing a vegetation mask with a disc: the one implementation, and the bound on its radius.

Rendered masks are exact per leaf, and a model's masks have small holes inside a crown (bare
branches, gaps between leaves) that the paper's column histograms read as free columns. A
morphological closing with a disc of `radius` pixels fills gaps narrower than about 2 x radius and
leaves wider openings (the free corridor, the sky above the canopy) alone. Every closing in segmin
is this one: the training label's (`data.label_closing`, segmin.data.canopy_region), `eval-seg
--truth-closing`, the simulator's `perception.mask_closing` and the navigator's `mask_closing`
(the robot runtime, which is why it lives at the ground of the layers: the runtime needs no
training code for it). numpy and OpenCV only.

Every radius is checked once, when its config or flag is read, against `MAX_CLOSING_RADIUS`.
"""

from __future__ import annotations

import cv2
import numpy as np

MAX_CLOSING_RADIUS = 112
"""The largest closing radius, px: half the models' 224 px input width. At the navigator's scale
(radii are px at 224 px of width) a disc this wide spans the whole frame, so a larger one closes
nothing more; on a stored photo it already fills gaps of a tenth of a 1920 px frame (the label
uses 4) and costs seconds a frame. A radius of 100000 was a typo that ran out of memory minutes
later (the disc alone is 200001 px square)."""

REFERENCE_WIDTH = 224
"""The width (px) at which the navigator's radius is given: the simulator's camera and the models'
input width. One radius then means the same on a 224 px simulated camera and a 640 x 480 RealSense."""


def check_closing_radius(radius: object, name: str = "label closing radius") -> int:
    """`radius` if it is an integer in [0, MAX_CLOSING_RADIUS], else ValueError naming `name`
    (the config field or flag)."""
    if isinstance(radius, bool) or not isinstance(radius, int) or not 0 <= radius <= MAX_CLOSING_RADIUS:
        raise ValueError(f"{name} must be an integer from 0 to {MAX_CLOSING_RADIUS} px, got {radius!r}")
    return radius


def canopy_region(mask: np.ndarray, radius: int) -> np.ndarray:
    """`mask` (HxW, 0/1 or bool) closed with a disc of `radius` px; same dtype; 0 = unchanged."""
    if check_closing_radius(radius) == 0:
        return mask
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    # Pad by the radius so vegetation at the frame edge is closed as if the scene went on.
    padded = cv2.copyMakeBorder(mask.astype(np.uint8), radius, radius, radius, radius, cv2.BORDER_REPLICATE)
    closed = cv2.morphologyEx(padded, cv2.MORPH_CLOSE, disc)[radius:-radius, radius:-radius]
    return closed.astype(mask.dtype)


def close_mask(mask: np.ndarray, radius: int) -> np.ndarray:
    """`mask` (bool H x W) closed with a disc of `radius` px at `REFERENCE_WIDTH`; itself when 0.

    A mask of another width is closed at the reference width and scaled back, which also keeps
    the cost flat (a disc of 23 px on a 640 px mask takes ten times longer than 8 px at 224).
    Vegetation is never removed: the result is the mask or-ed with its closing."""
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
