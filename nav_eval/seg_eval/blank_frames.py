"""How much crop a model paints on frames that hold none: all black, all white, one uniform colour.

A camera with its cap on, a lens flooded by the sun, a frame of a failing driver: none holds a
plant, and a model that paints part of them as crop gives the navigator rows that are not there
(the column histogram of a uniform frame should be flat and empty). eval-seg runs these frames
through the model beside the photos and reports the share of each frame painted; a release model
must stay under `BLANK_FRAME_LIMIT` on every one (the shipped trees model does not yet).
"""

from __future__ import annotations

import numpy as np

from segmin.nav_eval.seg_eval.predictor import Predictor

BLANK_FRAME_LIMIT = 0.01
BLANK_FRAMES: dict[str, tuple[int, int, int]] = {
    "black": (0, 0, 0),
    "white": (255, 255, 255),
    "grey": (128, 128, 128),
    "sky_blue": (135, 180, 230),
    "soil_brown": (120, 90, 60),
    "leaf_green": (70, 130, 50),
}


def blank_frame_shares(predictor: Predictor) -> dict[str, float]:
    """Share of pixels painted as crop on each uniform frame, at the model's input size."""
    height, width = predictor.input_size
    shares = {}
    for name, colour in BLANK_FRAMES.items():
        frame = np.empty((height, width, 3), np.uint8)
        frame[:] = colour
        _, mask = predictor.predict(frame)
        shares[name] = float(mask.mean())
    return shares
