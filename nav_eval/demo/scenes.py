"""Analytic mask + depth frames for the navigator demo, ray-cast in numpy (no simulator needed).

A row is modelled as a vertical sheet of foliage with holes on each side of the robot, an
optional canopy slab closing over the row (tall trees; optionally with a free band over the
corridor, as a pergola's), optional trunks (vertical cylinders, not vegetation) in the row lines,
and flat ground. Rays from a camera
mounted like the paper's (tilted 15 degrees up, about 69 degrees field of view) hit the nearest
surface; its planar depth and whether it is vegetation give the depth frame and the mask. This
is enough to show what SegMin, SegMinD and SegZeros do on typical scenes, in milliseconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DemoScene:
    """One row scene seen from one robot pose (metres, radians)."""

    name: str
    half_gap: float  # distance from the row centre to each foliage sheet
    foliage_low: float  # foliage height range on the sheets
    foliage_high: float
    canopy_base: float | None  # height of a canopy slab over the row, None for open sky
    row_length: float
    lateral_offset: float = 0.0  # robot position left (+) of the row centre
    yaw: float = 0.0  # robot heading, positive turns left
    hole_fraction: float = 0.25
    depth_threshold: float = 5.0
    canopy_opening: float = 0.0  # width of a free band in the canopy slab over the row centre
    trunk_spacing: float | None = None  # trunks every this many metres along both row lines, None for none
    trunk_radius: float = 0.12


DEMO_SCENES: tuple[DemoScene, ...] = (
    DemoScene(
        "vineyard, centred",
        half_gap=0.9,
        foliage_low=0.4,
        foliage_high=2.0,
        canopy_base=None,
        row_length=20.0,
        depth_threshold=5.0,
    ),
    DemoScene(
        "vineyard, 0.3 m left, 8 deg left",
        half_gap=0.9,
        foliage_low=0.4,
        foliage_high=2.0,
        canopy_base=None,
        row_length=20.0,
        lateral_offset=0.3,
        yaw=math.radians(8),
        depth_threshold=5.0,
    ),
    DemoScene(
        "tall trees, canopy over the row",
        half_gap=3.5,
        foliage_low=0.0,
        foliage_high=9.0,
        canopy_base=4.5,
        row_length=30.0,
        lateral_offset=-0.4,
        depth_threshold=10.0,
    ),
    DemoScene(
        "end of the row",
        half_gap=0.9,
        foliage_low=0.4,
        foliage_high=2.0,
        canopy_base=None,
        row_length=0.0,
        depth_threshold=5.0,
    ),
)


# Merged crowns from 1.6 m over a 7 m corridor, trunks every 4 m: SegCorridor's trunk mode (bench).
CLOSED_CANOPY_SCENE = DemoScene(
    "orchard, merged crowns over trunks, 0.3 m right",
    half_gap=3.5,
    foliage_low=1.6,
    foliage_high=4.0,
    canopy_base=2.5,
    row_length=30.0,
    lateral_offset=-0.3,
    hole_fraction=0.0,
    depth_threshold=10.0,
    trunk_spacing=4.0,
)


def render_scene(
    scene: DemoScene,
    *,
    size: int = 224,
    hfov_deg: float = 69.0,
    camera_height: float = 0.4,
    tilt_deg: float = 15.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Return (mask bool, depth float32 metres, 0 = no return) for the scene.

    One projection loop per kind of scene element (rows, gaps, canopy, ground), in one function so
    the painter's order of the elements is visible in one place."""
    focal = (size / 2) / math.tan(math.radians(hfov_deg) / 2)
    centre = (size - 1) / 2
    cols, rows = np.meshgrid(np.arange(size), np.arange(size))
    right_c = (cols - centre) / focal
    down_c = (rows - centre) / focal
    tilt = math.radians(tilt_deg)
    cos_y, sin_y = math.cos(scene.yaw), math.sin(scene.yaw)
    # Camera axes in the world (x along the row, y left, z up), before yaw.
    forward = np.array([math.cos(tilt), 0.0, math.sin(tilt)])
    right = np.array([0.0, -1.0, 0.0])
    down = np.array([math.sin(tilt), 0.0, -math.cos(tilt)])
    rays = forward + right_c[..., None] * right + down_c[..., None] * down
    yawed = np.stack(
        [cos_y * rays[..., 0] - sin_y * rays[..., 1], sin_y * rays[..., 0] + cos_y * rays[..., 1], rays[..., 2]],
        axis=-1,
    )
    origin = np.array([0.0, scene.lateral_offset, camera_height])
    holes = _HoleTexture(seed, scene.hole_fraction)

    best = np.full((size, size), np.inf)
    vegetation = np.zeros((size, size), dtype=bool)

    def consider(t: np.ndarray, is_vegetation: bool) -> None:
        closer = t < best
        best[closer] = t[closer]
        vegetation[closer] = is_vegetation

    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(yawed[..., 2] < 0, -origin[2] / yawed[..., 2], np.inf)
        consider(t_ground, False)
        for side in (+1.0, -1.0):
            t = (side * scene.half_gap - origin[1]) / yawed[..., 1]
            hit = origin + t[..., None] * yawed
            inside = (t > 0) & (hit[..., 0] > 0.3) & (hit[..., 0] < scene.row_length)
            inside &= (hit[..., 2] >= scene.foliage_low) & (hit[..., 2] <= scene.foliage_high)
            inside &= ~holes(hit[..., 0], hit[..., 2], side)
            consider(np.where(inside, t, np.inf), True)
        if scene.canopy_base is not None:
            t = (scene.canopy_base - origin[2]) / yawed[..., 2]
            hit = origin + t[..., None] * yawed
            inside = (t > 0) & (hit[..., 0] > 1.0) & (hit[..., 0] < scene.row_length)
            inside &= ~holes(hit[..., 0], hit[..., 1], 0.0) & (np.abs(hit[..., 1]) >= scene.canopy_opening / 2)
            consider(np.where(inside, t, np.inf), True)
        if scene.trunk_spacing is not None:
            top = scene.canopy_base if scene.canopy_base is not None else scene.foliage_high
            for x_trunk in np.arange(scene.trunk_spacing / 2, scene.row_length, scene.trunk_spacing):
                for side in (+1.0, -1.0):
                    consider(
                        _cylinder_hits(origin, yawed, x_trunk, side * scene.half_gap, scene.trunk_radius, top), False
                    )

    # The ray's forward component is 1, so the ray parameter is the planar depth.
    depth = np.where(np.isfinite(best), best, 0.0).astype(np.float32)
    return vegetation & np.isfinite(best), depth


def _cylinder_hits(origin: np.ndarray, rays: np.ndarray, x: float, y: float, radius: float, top: float) -> np.ndarray:
    """Ray parameter of the first hit on the vertical cylinder at (x, y) from the ground to `top`
    (inf for a miss): the ray's (x, y) path meets the circle where |o + t d - c|^2 = r^2."""
    dx, dy = rays[..., 0], rays[..., 1]
    ox, oy = origin[0] - x, origin[1] - y
    a = dx * dx + dy * dy
    b = 2.0 * (ox * dx + oy * dy)
    c = ox * ox + oy * oy - radius * radius
    disc = b * b - 4.0 * a * c
    t = np.where(disc >= 0, (-b - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a), np.inf)
    z = origin[2] + t * rays[..., 2]
    return np.where((t > 0) & (z >= 0) & (z <= top), t, np.inf)


class _HoleTexture:
    """Deterministic gaps in the foliage on a 15 cm grid, so masks have holes like real leaves."""

    def __init__(self, seed: int, fraction: float, cell: float = 0.15, extent: int = 512) -> None:
        self.cell = cell
        self.extent = extent
        rng = np.random.default_rng(seed)
        self.grids = {side: rng.random((extent, extent)) < fraction for side in (-1.0, 0.0, 1.0)}

    def __call__(self, a: np.ndarray, b: np.ndarray, side: float) -> np.ndarray:
        finite = np.isfinite(a) & np.isfinite(b)
        ia = np.floor(np.where(finite, a, 0) / self.cell).astype(np.int64) % self.extent
        ib = np.floor(np.where(finite, b, 0) / self.cell).astype(np.int64) % self.extent
        return self.grids[side][ia, ib]
