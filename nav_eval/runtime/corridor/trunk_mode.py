"""Under a roof: its opening, or the rows found on their trunks (step 7 of the algorithm in
docs/reference/equations.md).

Under a pergola SegMinD's column follows the roof's free band, so an opening hands the command to
the fallback; under the merged crowns of tall trees there is no such column, and the rows stand
on their trunks and posts, which the canopy mask leaves out but the depth camera sees.
"""

from __future__ import annotations

import numpy as np

from ..camera import CameraGeometry
from .config import (
    GROUND_BANDS,
    GROUND_MIN_POINTS,
    ROOF_BIN,
    TRUNK_H_MAX,
    TRUNK_H_MIN,
    TRUNK_MAX_EXCESS_GREEN,
    TRUNK_MAX_LATERAL,
    TRUNK_STRIDE,
    TRUNK_X_MAX,
    WIDTH_MEMORY,
    CorridorConfig,
)
from .rays import StridedRays
from .row_fit import polyval


def ground_plane(x: np.ndarray, y: np.ndarray, h: np.ndarray) -> tuple[float, float, float]:
    """The ground ahead as a plane h = a + b x + c y in the robot's frame, fitted to the low
    non-vegetation points, (0, 0, 0) (the plane the robot stands on) with too few of them.

    A robot pitched by a bump sees the level ground ahead rise by x tan(pitch): at 0.09 rad the
    soil 4-9 m ahead stood 0.3-0.8 m above the robot's plane, inside the trunks' height band,
    and the trunk-to-trunk width shrank from 7 m to 2 m until the robot left the row (two of the
    six high-trees layouts). The ground is most of the non-vegetation pixels, so least squares
    on the points near the current plane, the band narrowed each round, finds it; trunks and
    posts stand above it and fall out of the band."""
    plane = np.zeros(3)
    design = np.stack([np.ones_like(x), x, y], axis=1)
    for band in GROUND_BANDS:
        near = np.abs(h - design @ plane) <= band
        if np.count_nonzero(near) < GROUND_MIN_POINTS:
            return 0.0, 0.0, 0.0
        plane = np.linalg.lstsq(design[near], h[near], rcond=None)[0]
    a, b, c = (float(value) for value in plane)
    return a, b, c


def roof_opening(lateral: np.ndarray, reach: float) -> float:
    """Width (m) of the widest band along the robot, within `reach` (`roof_opening_reach`) of it (`lateral`:
    the roof points' y), that holds (almost) no roof point: 0.75-1.25 m under the test pergola, 0-0.25 m
    under the merged crowns of the high trees (docs/nav_eval.md)."""
    counts = np.histogram(lateral, bins=round(2 * reach / ROOF_BIN), range=(-reach, reach))[0]
    widest = run = 0
    for empty in counts < 2:
        run = run + 1 if empty else 0
        widest = max(widest, run)
    return widest * ROOF_BIN


class TrunkFinder:
    """The centreline between the trunks of the two rows, and the running trunk-to-trunk `width`
    (None until both sides were seen; it gates the next rows' trunks out)."""

    def __init__(self, config: CorridorConfig, camera: CameraGeometry, rays: StridedRays) -> None:
        self.config = config
        self.camera = camera
        self.rays = rays
        self.reset()

    def reset(self) -> None:
        """Forget the trunk-to-trunk width (a new run)."""
        self.width: float | None = None

    def centreline(
        self,
        fused: np.ndarray,
        depth_m: np.ndarray,
        attitude: tuple[float, float] | None,
        rgb: np.ndarray | None,
        split: tuple[float, ...],
    ) -> tuple[tuple[float, ...] | None, str]:
        """Under a roof: the centreline between the trunks (and posts) of the two rows, from the
        non-vegetation pixels standing `trunk_h_min`-`trunk_h_max` above the ground."""
        config = self.config
        pixel_index, rays = self.rays.grid(fused.shape, TRUNK_STRIDE)
        chosen = np.flatnonzero(~fused[::TRUNK_STRIDE, ::TRUNK_STRIDE])
        if rgb is not None:  # bark and posts are not green; leaves the mask missed are
            rows, cols = np.divmod(pixel_index[chosen], fused.shape[1])
            colour = rgb[rows, cols].astype(np.float32)
            excess_green = 2.0 * colour[:, 1] - colour[:, 0] - colour[:, 2]
            chosen = chosen[excess_green <= TRUNK_MAX_EXCESS_GREEN]
        z = depth_m.ravel()[pixel_index[chosen]]
        valid = np.flatnonzero(z > 0)
        ray_columns = np.take(rays, chosen[valid], axis=1)
        # The height band is measured from the ground ahead (`ground_plane`, in the robot's own
        # frame, not levelled): across a slope the level plane through the robot cuts the uphill
        # row's ground and passes under the downhill row's crowns, and a bump under the robot tilts
        # its own plane against the ground ahead. The positions are levelled (trunks stand along
        # gravity).
        x, y, h = self.camera.points_on_rays(ray_columns, z[valid])
        ahead = (x >= config.x_min) & (x <= TRUNK_X_MAX)
        x, y, h = x[ahead], y[ahead], h[ahead]
        a, b, c = ground_plane(x, y, h)
        above_ground = h - (a + b * x + c * y)
        if attitude is not None:
            x, y, _ = self.camera.level(x, y, h, attitude)
        ok = (above_ground >= TRUNK_H_MIN) & (above_ground <= TRUNK_H_MAX)
        x, y = x[ok], y[ok]
        offset = y - polyval(x, split)
        # Once the trunk-to-trunk width w is known, the next rows' trunks (at 1.5 w) are left out.
        reach = TRUNK_MAX_LATERAL if self.width is None else min(TRUNK_MAX_LATERAL, self.width)
        near = np.abs(offset) <= reach
        # A trunk or two a side give no reliable heading: the centreline is taken along the robot
        # (the goal is then the middle between the trunks ahead, which also turns out a heading error).
        shape = (0.0,) * config.degree  # as many coefficients as the row fits give: the centreline
        # is averaged with the next one coefficient by coefficient
        sides, counts = {}, {}
        for name, chosen_side in (("left", near & (offset > 0)), ("right", near & (offset <= 0))):
            counts[name] = int(np.count_nonzero(chosen_side))
            if counts[name] >= config.trunk_min_points:
                sides[name] = float(np.median(y[chosen_side]))
        if len(sides) == 2 and sides["left"] > sides["right"]:
            width = sides["left"] - sides["right"]
            memory = WIDTH_MEMORY
            self.width = width if self.width is None else (1 - memory) * self.width + memory * width
            return ((sides["left"] + sides["right"]) / 2.0, *shape), "trunks"
        if len(sides) >= 1 and self.width is not None:
            name, row = max(sides.items(), key=lambda side: counts[side[0]])  # the side with more support
            return (row + (-self.width / 2.0 if name == "left" else self.width / 2.0), *shape), "trunks"
        return None, "fallback"
