"""The masks a navigator steers on: checked, optionally closed, fused over the last N.

The paper fuses the last N masks with a logical OR (Navone et al., section 2): one frame's missed
leaves do not open a free column. Every navigator keeps that window the same way, so it is one
piece that the paper's `Navigator` and SegCorridor's `CorridorNavigator` both hold, with the
mask check that refuses a probability map (a silently wrong mask would steer the robot).
numpy and OpenCV only (part of the bare robot install).
"""

from __future__ import annotations

import numpy as np

from segmin.common.mask_closing import close_mask

_THRESHOLD_HINT = "threshold it first, e.g. mask = probabilities > 0.5"


class MaskFusion:
    """A ring of the last `frames` masks, each closed with a disc of `closing` px first (0: as
    given; nav_eval.runtime.mask_closing), and their OR.

    Each mask carries its frame time, so `fused(not_before=...)` can leave out stale masks (the
    runtime's `RowFollower` does, when the camera stalls). A mask of another size than the
    window's starts a new window.
    """

    def __init__(self, frames: int, closing: int = 0) -> None:
        self.frames = frames
        self.closing = closing
        self.reset()

    def reset(self) -> None:
        """Forget every mask."""
        self._masks: np.ndarray | None = None
        self._stamps = np.full(self.frames, -np.inf)
        self._count = 0

    def push(self, mask: np.ndarray, stamp: float = 0.0) -> None:
        """Add one bool mask (already checked: `validated_mask`) taken at `stamp` seconds; no
        reallocation while the size stays."""
        n = self.frames
        mask = close_mask(mask, self.closing)  # the mask itself when 0
        if self._masks is None or self._masks.shape[1:] != mask.shape:
            self._masks = np.zeros((n, *mask.shape), dtype=bool)
            self._stamps[:] = -np.inf
            self._count = 0
        self._masks[self._count % n] = mask
        self._stamps[self._count % n] = float(stamp)
        self._count += 1

    def fused(self, not_before: float | None = None) -> np.ndarray | None:
        """Logical OR of the masks in the window; with `not_before`, only those stamped at or
        after it (stale masks are left out). None when no mask qualifies."""
        if self._masks is None or self._count == 0:
            return None
        if not_before is None:
            filled = min(self._count, self.frames)
            window = self._masks if filled == self.frames else self._masks[:filled]
        else:
            # Slots never filled are stamped -inf, so they only pass a not_before of -inf, and
            # then they add nothing to the OR (they are all False).
            keep = self._stamps >= not_before
            if not keep.any():
                return None
            window = self._masks if keep.all() else self._masks[keep]
        return np.asarray(window.any(axis=0))  # an array (numpy's stubs also allow a scalar)


def validated_mask(mask: np.ndarray) -> np.ndarray:
    """Check a mask's shape and values; return it as bool (no depth needed, so pushing a mask
    into the fusion window allocates nothing)."""
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask must be a 2-D h x w array, got shape {mask.shape}")
    if mask.size == 0:
        raise ValueError(f"mask must not be empty, got shape {mask.shape}")
    return _bool_mask(mask)


def _bool_mask(mask: np.ndarray) -> np.ndarray:
    """A bool mask from bool, {0, 1} or {0, 255} integers; anything else is refused.

    `mask != 0` on a probability map would call every pixel above 0 vegetation and steer on a
    silently wrong mask. Two reductions (min, max) keep the check cheap (other integer types
    than uint8 pay one more pass for a 0/255 mask).
    """
    if mask.dtype == bool:
        return mask
    if not np.issubdtype(mask.dtype, np.integer):
        raise ValueError(
            f"mask dtype is {mask.dtype}: expected bool or an integer 0/1 or 0/255 mask "
            f"(a probability map? {_THRESHOLD_HINT})"
        )
    if mask.dtype == np.uint8:
        # Seen as int8, 255 is -1: {0, 1} spans 0..1 and {0, 255} spans -1..0, and any other
        # byte widens the span, so min and max alone decide.
        signed = mask.view(np.int8)
        low, high = int(signed.min()), int(signed.max())
        if low >= 0 and high <= 1:
            return mask.view(bool)
        if low >= -1 and high <= 0:
            return mask != 0
        low, high = int(mask.min()), int(mask.max())
    else:
        low, high = int(mask.min()), int(mask.max())
        if low >= 0 and (high <= 1 or (high == 255 and np.count_nonzero(mask) == np.count_nonzero(mask == 255))):
            return mask != 0
    raise ValueError(
        f"mask values range over {low}..{high}: expected only 0/1 or 0/255 "
        f"(a label or probability map? {_THRESHOLD_HINT})"
    )
