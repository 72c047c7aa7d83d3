"""The canopy-region label: the rendered leaf mask with the small gaps between leaves closed.

Rendered masks are exact per leaf: the sky and grass seen between two shoots are 0. People who
label real rows draw a polygon around the canopy, so the gaps between shoots are 1 in their
masks (the 8 real vineyard photos shipped in data/real are labelled that way). A model trained
on the exact masks learns to leave those gaps out and scores them as missed canopy. A
morphological closing with a disc of `radius` pixels (at the frame's stored resolution) fills
gaps narrower than about 2 x radius and leaves wider openings (the free corridor, the sky
above the canopy) alone. `radius` 0 keeps the exact mask.

The closing and the bound on its radius are segmin's one implementation,
segmin.common.mask_closing, which the simulator and the robot runtime's navigator use too; the
names are importable from here as before.
"""

from __future__ import annotations

from segmin.common.mask_closing import MAX_CLOSING_RADIUS, canopy_region, check_closing_radius

__all__ = ["MAX_CLOSING_RADIUS", "canopy_region", "check_closing_radius"]
