"""The mask tint of every figure (training previews, synth contact sheets, nav-eval frames and videos).

One function so the figures agree on how a mask is drawn; each keeps its own colour and opacity.
"""

from __future__ import annotations

from collections.abc import Sequence

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
    out[selected] = (keep * out[selected] + opacity * np.asarray(colour)).astype(np.uint8)
    return out
