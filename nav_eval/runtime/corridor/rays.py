"""The camera's rays on a strided pixel grid, cached per image shape and stride.

SegCorridor back-projects only every `stride`-th pixel in both directions (the rows' points) or
every `trunk_stride`-th (the trunk test). The rays of those pixels depend on the camera alone,
so they are computed once per image shape and stride; a step then looks up only the pixels it
keeps instead of masking whole images.
"""

from __future__ import annotations

import numpy as np

from ..camera import CameraGeometry


class StridedRays:
    """For every `s`-th pixel in both directions, in row-major order: its flat index in the full
    image and the camera's ray coefficients (a 3 x n array)."""

    def __init__(self, camera: CameraGeometry) -> None:
        self.camera = camera
        self._grids: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}

    def grid(self, shape: tuple[int, int], s: int) -> tuple[np.ndarray, np.ndarray]:
        """(flat pixel indices, 3 x n ray coefficients) of the `s`-strided grid of an image of `shape`."""
        # A named key: mypy reads `grids[(*shape, s)]` as Python 3.11's unparenthesised star index.
        key = (*shape, s)
        if key not in self._grids:
            rows, cols = np.meshgrid(np.arange(0, shape[0], s), np.arange(0, shape[1], s), indexing="ij")
            rays = self.camera.ray_coefficients(rows.ravel().astype(np.float32), cols.ravel().astype(np.float32))
            self._grids[key] = ((rows * shape[1] + cols).ravel(), np.stack(rays).astype(np.float32))
        return self._grids[key]
