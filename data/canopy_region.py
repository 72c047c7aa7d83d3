"""The canopy-region label: the rendered leaf mask with the small gaps between leaves closed.

Rendered masks are exact per leaf: the sky and grass seen between two shoots are 0. People who
label real rows draw a polygon around the canopy, so the gaps between shoots are 1 in their
masks (the 8 real vineyard photos shipped in data/real are labelled that way). A model trained
on the exact masks learns to leave those gaps out and scores them as missed canopy. A
morphological closing with a disc of `radius` pixels (at the frame's stored resolution) fills
gaps narrower than about 2 x radius and leaves wider openings (the free corridor, the sky
above the canopy) alone. `radius` 0 keeps the exact mask.

Every closing radius (the label's `data.label_closing`, `eval-seg --truth-closing`, the
navigator's `mask_closing`, the simulator's `perception.mask_closing`) is checked here, once, when
its config or flag is read, against `MAX_CLOSING_RADIUS`.
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
