"""The mask tint and depth colours of every figure (training previews, synth contact sheets,
nav-eval frames and videos, renderer comparisons).

One function each so the figures agree on how a mask and a depth map are drawn; each figure keeps
its own mask colour and opacity.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

GREEN: tuple[int, int, int] = (0, 255, 0)
MAGENTA: tuple[int, int, int] = (255, 0, 200)  # synth contact sheets: stands out on green canopies


def tint_mask(rgb: np.ndarray, mask: np.ndarray, colour: Sequence[int] = GREEN, opacity: float = 0.5) -> np.ndarray:
    """A uint8 copy of `rgb` whose `mask` pixels are blended towards `colour` with `opacity`.

    The image weight is rounded so that e.g. opacity 0.55 weights the image by exactly 0.45
    (1 - 0.55 is 0.44999999999999996 in binary), which keeps earlier figures bit-identical.
    """
    out = np.array(rgb, dtype=np.uint8, copy=True)
    selected = np.asarray(mask, dtype=bool)
    keep = round(1.0 - opacity, 6)
    # The blend of every value a channel can take, by the per-pixel formula (float64, truncated):
    # looked up, the result is the same to the bit at a tenth of the cost, which the live view's
    # 30 frames a second need.
    table = (keep * np.arange(256)[:, None] + opacity * np.asarray(colour)).astype(np.uint8)
    tinted = cv2.LUT(out, table.reshape(256, 1, 3))
    out[selected] = tinted[selected]
    return out


def depth_colours(depth: np.ndarray, far: float = 15.0) -> np.ndarray:
    """RGB uint8 picture of planar depth in metres: near warm, `far` and beyond cold, no return black."""
    d = np.clip(depth / far, 0, 1)
    image = cv2.applyColorMap((255 - d * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[:, :, ::-1].copy()
    image[depth <= 0] = 0
    return image
